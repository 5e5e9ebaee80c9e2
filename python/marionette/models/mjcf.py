"""MuJoCo 2.2.2 models (MJCF) of the robots, the objects and the scenes.

Contact filtering (MuJoCo collides geoms a, b when contype_a & conaffinity_b or
contype_b & conaffinity_a, and never a body with its parent):

=============  =======  ===========  ==========================================================
class          contype  conaffinity  touches
=============  =======  ===========  ==========================================================
floor          1        4|16         soles, objects
robot_body     2        0            fixtures, objects (never itself, never the floor)
robot_sole     4        1|16|32      floor, objects, fixtures
robot_hand     8        16|32        objects, fixtures (grippers, tools; never the robot)
object         16       all          everything (plank, ball, box, drill: free bodies)
fixture        32       2|4|8|16     robot, objects (table, part, pedestal, bar: mocap bodies)
visual, tag    0        0            nothing (markings, AprilTag textures, tool bits)
=============  =======  ===========  ==========================================================

Servos are ``<general biastype="affine" gainprm="kp" biasprm="0 -kp -kv">``:
tau = kp (ctrl - q) - kv dq, clamped to the URDF effort. A controller that wants
tau = kp (q* - q) + kv (dq* - dq) sends ctrl = q* + (kv / kp) dq*. The implicit integrator
(``integrator="implicit"``, MuJoCo >= 2.2) differentiates the -kv dq term, so stiff servos are
stable at the 1 ms step.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from marionette.robots import (
    RobotDescription,
    mujoco_layout,
    pinocchio_to_mujoco,
    robot,
    semantics,
)

from . import apriltag
from .convex_parts import convex_parts
from .semantics import Semantics
from .urdf import Urdf, mimic_equality, parse_urdf, urdf_to_mjcf
from .xml_util import fmt, fmt_vec, homogeneous, matrix_to_quat_wxyz, sub

TIMESTEP = 0.001
CAMERA_WIDTH, CAMERA_HEIGHT = 640, 480
# Orbbec Astra and Asus Xtion RGB: about 45 deg vertical field of view,
# fy = 240 / tan(22.5 deg) = 579.4 px at 640 x 480.
CAMERA_FOVY_DEG = 45.0
TAG_THICKNESS = 0.001  # [m] the tag plate sinks this deep below its printed face
TAG_PIXELS_PER_CELL = 16

CLASSES = {
    "floor": dict(contype="1", conaffinity="20"),
    "robot_body": dict(contype="2", conaffinity="0"),
    # Stiffer than MuJoCo's default contact (time constant 4 ms instead of 20 ms, critically
    # damped): a 95 kg humanoid's soles sink 0.3 mm instead of 0.65 mm into the floor.
    "robot_sole": dict(
        contype="4",
        conaffinity="49",
        friction="1 0.005 0.0001",
        solref="0.004 1",
        rgba="0.2 0.2 0.2 1",
    ),
    "robot_hand": dict(contype="8", conaffinity="48", friction="1 0.005 0.0001"),
    # A gripper's jaws (robot.yaml grippers[].jaws), which hold objects by friction: condim 4
    # (torsional friction: a pinched object does not spin about the squeeze axis) and a stiff
    # contact (5 ms, critically damped) that wins over the object's (solmix), so that a closed
    # gripper holds a box instead of letting it creep down its pads (UR10 box at 5 N per jaw, lift
    # and 0.5 m carry at 0.5 m/s: creep 0.29 -> 0.08 mm/s, 0.26 mm after the hold; MuJoCo's
    # default pads with pyramidal cones or impratio 1 drop it by centimetres).
    "robot_pad": dict(
        contype="8",
        conaffinity="48",
        condim="4",
        friction="1 0.005 0.0001",
        solref="0.005 1",
        solmix="1000",
    ),
    "object": dict(contype="16", conaffinity="63", friction="0.8 0.005 0.0001"),
    "fixture": dict(contype="32", conaffinity="30"),
    "visual": dict(contype="0", conaffinity="0"),
    "tag": dict(contype="0", conaffinity="0"),
}
SITE_GROUP = "5"  # hidden by default in the viewer


@dataclass
class Part:
    """A piece of a model: bodies for the worldbody, assets, actuators, sensors, qpos/ctrl."""

    bodies: list[ET.Element] = field(default_factory=list)
    meshes: dict[str, tuple[str, tuple[float, float, float]]] = field(default_factory=dict)
    textures: dict[str, str] = field(default_factory=dict)  # material name -> texture file
    tag_meshes: dict[str, float] = field(default_factory=dict)  # mesh name -> printed size
    actuators: list[ET.Element] = field(default_factory=list)
    sensors: list[ET.Element] = field(default_factory=list)
    equalities: list[ET.Element] = field(default_factory=list)
    qpos: list[float] = field(default_factory=list)  # reference configuration, MuJoCo order
    ctrl: list[float] = field(default_factory=list)
    mocap_pos: list[float] = field(default_factory=list)
    mocap_quat: list[float] = field(default_factory=list)


# --- robots ------------------------------------------------------------------------------------


# Planar base (MuJoCo side): joint name, type, axis, force limit [N or N m].
PLANAR_BASE = (
    ("root_x", "slide", (1, 0, 0), 1000.0),
    ("root_y", "slide", (0, 1, 0), 1000.0),
    ("root_yaw", "hinge", (0, 0, 1), 500.0),
)


class RobotModelError(ValueError):
    """A robot's files cannot make an MJCF; the message says what to fix in which file."""


def hand_links(desc: RobotDescription, urdf: Urdf) -> set[str]:
    """The links that touch objects (class robot_hand): the subtrees of ``simulation/hand_links``
    (default: the grippers' links) and of the link each gripper's finger joint is mounted on
    (its fixed jaw and its fingers, also when the gripper frame sits on a link beside them)."""
    roots = [link for link in desc.hand_links if link in urdf.links]
    for g in desc.data.get("grippers", []):
        joint = urdf.joints.get(g.get("joint") or "")
        if joint is not None:
            roots.append(joint.parent)
    return {link for root in roots for link in urdf.subtree(root)}


def robot_part(
    name: str | Path, q_reference: np.ndarray, X_WB: np.ndarray | None = None, models_dir=None
) -> Part:
    """Robot ``name`` with its base at X_WB (fixed bases) or its reference configuration.
    Mesh files are named relative to ``models_dir`` (the MJCF's meshdir; default: the parent of
    the robot's folder)."""
    desc = robot(name)
    urdf = parse_urdf(desc.urdf.read_text())
    for link in desc.hand_links:
        if link not in urdf.links:
            raise RobotModelError(
                f"{desc.semantics}: simulation/hand_links names {link!r}, not a link of "
                f"{desc.urdf.name}"
            )
    hands = hand_links(desc, urdf)
    pads = {link for links in desc.grip_bodies.values() for link in links}
    mesh_file = _mesh_namer(desc, models_dir)

    def geom_class(link: str) -> str:
        if link in pads:
            return "robot_pad"
        return "robot_hand" if link in hands else "robot_body"

    def armature(joint) -> float:  # a mimic's rotor is its driver's
        return desc.actuator(joint.mimic.joint if joint.mimic else joint.name).armature

    # The URDF's mimic joints (a parallel gripper's second finger) move in MuJoCo, tied to their
    # driver by equalities, so a closing gripper really squeezes; the controller's model keeps
    # them fixed. A robot whose moving fingers would wedge its objects keeps them fixed
    # (simulation/moving_mimics: false).
    tree = urdf_to_mjcf(
        urdf,
        mesh_file,
        f"{desc.name}/",
        geom_class,
        armature,
        mimics=desc.moving_mimics,
        collision_meshes=_convex_namer(desc, models_dir, hands | pads, mesh_file),
    )
    part = Part(meshes=dict(tree.meshes), equalities=[mimic_equality(j) for j in tree.mimics])
    root = tree.root
    if desc.base == "free_flyer":
        root.insert(0, ET.Element("freejoint", name="root_joint"))
    elif desc.base == "planar":
        for i, (jname, kind, axis, _) in enumerate(PLANAR_BASE):
            g = desc.actuator(jname)
            root.insert(
                i,
                ET.Element(
                    "joint",
                    {
                        "name": jname,
                        "type": kind,
                        "axis": fmt_vec(axis),
                        "limited": "false",
                        "armature": fmt(g.armature) if g.armature else "0",
                    },
                ),
            )
    if X_WB is not None:
        if desc.base != "fixed":
            raise ValueError(f"{name} has a {desc.base} base: place it with its configuration")
        _set_pose(root, X_WB)
    part.bodies.append(root)
    sem = semantics(name)
    _check_links(desc, tree.bodies, sem)
    _add_gripper_sites(tree.bodies, sem)
    _add_feet(desc, tree.bodies, part)
    for sensor, link in desc.force_torque_sensors:
        _add_force_torque_sensor(tree.bodies[link], sensor, part)
    for r in desc.range_finders:
        _add_range_finder(tree.bodies[r.frame], r.name, r.noise, part)
    if desc.imu_link is not None:
        _add_imu(tree.bodies[desc.imu_link], part)
    for tag in sem.tags:
        _add_tag(tree.bodies[tag.link], tag.id, tag.family, tag.size, tag.pose.matrix(), part)
    for camera in desc.cameras:
        cam = sub(
            tree.bodies[camera.frame],
            "camera",
            name=camera.name,
            mode="fixed",
            fovy=fmt(camera.fovy_deg),
        )
        # Optical frame: z along the view, y down. MuJoCo camera: looks along -z, y up.
        cam.set("quat", "0 1 0 0")
    # Actuators: the planar base first, then every URDF joint in MJCF (= Pinocchio) order.
    joints: list[tuple[str, str, float | None, float | None, float | None]] = (
        [(j, "slide" if k == "slide" else "hinge", None, None, f) for j, k, _, f in PLANAR_BASE]
        if desc.base == "planar"
        else []
    )
    joints += [(j.name, j.type, j.lower, j.upper, j.effort) for j in tree.joints]
    for jname, _, lo, hi, effort in joints:
        g = desc.actuator(jname)
        if not effort or effort <= 0:
            raise RobotModelError(
                f"{desc.urdf}: joint {jname!r} has no positive <limit effort=...>: its servo "
                f"needs a force limit; add one to the URDF"
            )
        part.actuators.append(
            ET.Element(
                "general",
                {
                    "name": jname,
                    "joint": jname,
                    "gaintype": "fixed",
                    "biastype": "affine",
                    "gainprm": fmt(g.kp),
                    "biasprm": fmt_vec([0, -g.kp, -g.kv]),
                    **(
                        {"ctrllimited": "true", "ctrlrange": fmt_vec([lo, hi])}
                        if lo is not None and hi is not None
                        else {"ctrllimited": "false"}
                    ),
                    "forcelimited": "true",
                    "forcerange": fmt_vec([-effort, effort]),
                },
            )
        )
    layout = mujoco_layout(root, part.equalities)
    qpos = pinocchio_to_mujoco(name, q_reference, layout=layout)
    part.qpos = [float(a) for a in qpos]
    n_base = {"free_flyer": 7, "planar": 0, "fixed": 0}[desc.base]
    part.ctrl = [float(a) for a, j in zip(qpos[n_base:], layout) if j.mimic is None]
    return part


def _convex_namer(
    desc: RobotDescription, models_dir, hand: set[str], mesh_file: Callable[[str], str]
) -> Callable[[str, str], list[str]]:
    """(link, URDF mesh URI) -> the MJCF mesh files of a collision mesh: a concave mesh of a
    ``hand`` link is given as its convex pieces (:mod:`.convex_parts`, kept in ``<robot
    folder>/convex_meshes``); any other mesh as itself."""
    import os

    base = Path(models_dir) if models_dir is not None else desc.directory.parent

    def files(link: str, uri: str) -> list[str]:
        file = mesh_file(uri)
        if link not in hand:
            return [file]
        relative = Path(os.path.relpath(base / file, desc.directory))
        if relative.parts[0] in ("meshes", "converted_meshes"):
            relative = Path(*relative.parts[1:])
        stem = desc.directory / "convex_meshes" / relative.with_suffix("")
        parts = convex_parts(base / file, stem)
        return [Path(os.path.relpath(p, base)).as_posix() for p in parts]

    return files


def _mesh_namer(desc: RobotDescription, models_dir) -> Callable[[str], str]:
    """URDF mesh URI -> MJCF mesh file relative to ``models_dir``: a file under the robot's
    ``meshes`` folder is named through the link ``<robot folder>/meshes``; a mesh MuJoCo 2.2
    cannot read (DAE) is converted to STL once, into ``<robot folder>/converted_meshes``."""
    import os

    folder = desc.directory
    base = Path(models_dir) if models_dir is not None else folder.parent
    meshes_root = None
    if desc.meshes is not None:
        meshes_root = desc.meshes.rstrip("/") + "/"

    def name(uri: str) -> str:
        if meshes_root is not None and uri.startswith(meshes_root):
            path = folder / "meshes" / uri.removeprefix(meshes_root)
        elif not uri.startswith("package://"):
            path = Path(uri) if Path(uri).is_absolute() else folder / uri
        else:
            raise RobotModelError(
                f"{desc.urdf}: mesh {uri} is outside the robot's meshes folder "
                f"({desc.meshes}); set 'meshes' in {desc.semantics} to the folder holding it"
            )
        if path.suffix.lower() not in (".stl", ".obj", ".msh"):
            path = convert_mesh(path, folder / "converted_meshes" / path.relative_to(folder))
        return Path(os.path.relpath(path, base)).as_posix()

    return name


def convert_mesh(source: Path, target_stem: Path) -> Path:
    """``source`` (any format trimesh reads: DAE, PLY, ...) written as ``target_stem``.stl, the
    format MuJoCo 2.2 reads; done once (the target is kept while it is newer than the source)."""
    target = target_stem.with_suffix(".stl")
    src = source.resolve()
    if target.exists() and target.stat().st_mtime >= src.stat().st_mtime:
        return target
    import trimesh

    mesh = trimesh.load(src, force="mesh")
    if mesh.is_empty:
        raise RobotModelError(f"{source}: no triangles to convert for MuJoCo")
    target.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(target)
    return target


def _check_links(desc: RobotDescription, bodies: dict[str, ET.Element], sem: Semantics) -> None:
    """Every link robot.yaml names exists in the URDF (a one-line error otherwise)."""
    named = [
        *(("grippers", g.link) for g in sem.grippers),
        *(("tags", t.link) for t in sem.tags),
        *(("contacts", c.link) for c in sem.contacts),
        *(("feet", f.frame) for f in desc.feet),
        *(("cameras", c.frame) for c in desc.cameras),
        *(("range_finders", r.frame) for r in desc.range_finders),
        *(("force_torque_sensors", link) for _, link in desc.force_torque_sensors),
        *((("imu", desc.imu_link),) if desc.imu_link else ()),
        *(("grippers/jaws", b) for bs in desc.grip_bodies.values() for b in bs),
    ]
    for key, link in named:
        if link not in bodies:
            raise RobotModelError(
                f"{desc.semantics}: {key} names {link!r}, which is not a link of "
                f"{desc.urdf.name} (frames must be links for MuJoCo: add a link with a fixed joint)"
            )


def _add_gripper_sites(bodies: dict[str, ET.Element], sem: Semantics) -> None:
    for g in sem.grippers:
        site = sub(
            bodies[g.link], "site", name=g.name, size="0.01", group=SITE_GROUP, rgba="0 0.8 0 1"
        )
        _set_pose(site, g.pose.matrix())


def _add_feet(desc: RobotDescription, bodies: dict[str, ET.Element], part: Part) -> None:
    """A contact box under each sole (bottom face on the sole plane) and its F/T sensor."""
    for foot in desc.feet:
        lx, ly, h = foot.size[0] / 2, foot.size[1] / 2, foot.thickness / 2
        body = bodies[foot.frame]
        sub(
            body,
            "geom",
            {
                "name": f"{foot.name}_sole",
                "class": "robot_sole",
                "type": "box",
                "size": fmt_vec([lx, ly, h]),
                "pos": fmt_vec([0, 0, h]),
            },
        )
        sub(body, "site", name=f"{foot.name}_sole", size="0.01", group=SITE_GROUP)
        part.sensors.append(
            ET.Element("force", name=f"{foot.name}_sole_force", site=f"{foot.name}_sole")
        )
        part.sensors.append(
            ET.Element("torque", name=f"{foot.name}_sole_torque", site=f"{foot.name}_sole")
        )


def _add_force_torque_sensor(body: ET.Element, name: str, part: Part) -> None:
    sub(body, "site", name=f"{name}_ft", size="0.01", group=SITE_GROUP)
    part.sensors.append(ET.Element("force", name=f"{name}_force", site=f"{name}_ft"))
    part.sensors.append(ET.Element("torque", name=f"{name}_torque", site=f"{name}_ft"))


def _add_range_finder(body: ET.Element, name: str, noise: float, part: Part) -> None:
    """A site on the frame's origin and the rangefinder that casts its ray along the site's +z
    (it ignores the site's own body, which is the frame's); ``noise`` [m, 1 sigma] is MuJoCo's
    declaration, which the simulator (marionette-controller, marionette-sim) adds."""
    sub(body, "site", name=name, size="0.004", group=SITE_GROUP, rgba="0.8 0 0 1")
    sensor = ET.Element("rangefinder", name=name, site=name)
    if noise > 0.0:
        sensor.set("noise", fmt(noise))
    part.sensors.append(sensor)


def _add_imu(body: ET.Element, part: Part) -> None:
    sub(body, "site", name="imu", size="0.01", group=SITE_GROUP)
    part.sensors += [
        ET.Element("gyro", name="imu_gyro", site="imu"),
        ET.Element("accelerometer", name="imu_accelerometer", site="imu"),
        ET.Element("framequat", name="imu_orientation", objtype="site", objname="imu"),
    ]


# --- objects -----------------------------------------------------------------------------------


def object_part(urdf: Urdf, sem: Semantics, sim: str, instance: str, X_WO: np.ndarray) -> Part:
    """The object of ``urdf`` with its declarations ``sem`` as body ``instance`` at X_WO: a
    free body (``sim`` = "free") or a mocap body ("mocap", a fixture moved by the scenario)."""
    cls = "object" if sim == "free" else "fixture"
    tree = urdf_to_mjcf(urdf, lambda uri: uri, f"{instance}/", lambda link: cls, visuals=True)
    body = tree.root
    body.set("name", instance)
    _set_pose(body, X_WO)
    part = Part()
    if sim == "free":
        body.insert(0, ET.Element("freejoint", name=instance))
        q = matrix_to_quat_wxyz(X_WO[:3, :3])
        part.qpos = [*X_WO[:3, 3], *q]
    else:
        body.set("mocap", "true")
        part.mocap_pos = list(X_WO[:3, 3])
        part.mocap_quat = list(matrix_to_quat_wxyz(X_WO[:3, :3]))
    for h in sem.handles:
        site = sub(body, "site", name=h.name, size="0.008", group=SITE_GROUP, rgba="0.8 0 0 1")
        _set_pose(site, h.pose.matrix())
    for g in sem.grippers:
        site = sub(body, "site", name=g.name, size="0.008", group=SITE_GROUP, rgba="0 0.8 0 1")
        _set_pose(site, g.pose.matrix())
    for tag in sem.tags:
        _add_tag(body, tag.id, tag.family, tag.size, tag.pose.matrix(), part)
    part.bodies.append(body)
    return part


def _add_tag(
    body: ET.Element, tag_id: int, family: str, size: float, X_BT: np.ndarray, part: Part
) -> None:
    """A textured plate whose top face is the printed tag (frame T: z out, x right, y up)."""
    printed = apriltag.printed_size(size, family)
    mesh = f"tag_plate_{fmt(printed * 1000)}mm"
    part.tag_meshes[mesh] = printed
    material = apriltag.texture_name(tag_id, family)
    part.textures[material] = f"textures/{material}.png"
    geom = sub(
        body,
        "geom",
        {
            "name": f"tag/{tag_id}",
            "class": "tag",
            "type": "mesh",
            "mesh": mesh,
            "material": material,
        },
    )
    _set_pose(geom, X_BT)
    site = sub(body, "site", name=f"tag/{tag_id}", size="0.005", group=SITE_GROUP)
    _set_pose(site, X_BT)


def tag_plate_mesh(name: str, printed: float) -> ET.Element:
    """A plate of ``printed`` x ``printed`` x TAG_THICKNESS, top face at z = 0, textured.

    Texture coordinates (MuJoCo: v = 0 is the first row of the PNG, the top of the tag
    image): the top-left image corner at (-s, +s) (x right, y up), top-right at (+s, +s).
    The bottom vertices repeat them; the plate's thin sides show a stretched edge row.
    """
    s, t = printed / 2, TAG_THICKNESS
    top = [(-s, s, 0), (s, s, 0), (s, -s, 0), (-s, -s, 0)]
    bottom = [(x, y, -t) for x, y, _ in top]
    uv = [(0, 0), (1, 0), (1, 1), (0, 1)]
    faces = [
        (0, 3, 2),
        (0, 2, 1),  # top, counter-clockwise seen from +z
        (4, 5, 6),
        (4, 6, 7),  # bottom
        (0, 1, 5),
        (0, 5, 4),
        (1, 2, 6),
        (1, 6, 5),
        (2, 3, 7),
        (2, 7, 6),
        (3, 0, 4),
        (3, 4, 7),
    ]
    normals = [(0, 0, 1)] * 4 + [(0, 0, -1)] * 4
    return ET.Element(
        "mesh",
        {
            "name": name,
            "vertex": " ".join(fmt_vec(v) for v in top + bottom),
            "normal": " ".join(fmt_vec(n) for n in normals),
            "texcoord": " ".join(fmt_vec(c) for c in uv + uv),
            "face": " ".join(fmt_vec(f) for f in faces),
        },
    )


# --- whole files -------------------------------------------------------------------------------


def assemble(
    model: str,
    parts: list[Part],
    comment: str,
    extra_world: Sequence[ET.Element] = (),
    floor: bool = True,
    keyframe: str = "reference",
) -> ET.Element:
    """A complete MJCF model of ``parts`` (meshdir and texturedir: the models/ directory)."""
    m = ET.Element("mujoco", model=model)
    m.append(ET.Comment(f" {comment} "))
    sub(
        m,
        "compiler",
        angle="radian",
        meshdir="..",
        texturedir="..",
        autolimits="true",
        inertiafromgeom="false",
        balanceinertia="true",
    )
    # Elliptic friction cones with impratio 10: feet and held objects creep 5x less (the
    # bundled humanoid standing: 0.1 mm in 5 s instead of 0.5 mm).
    sub(m, "option", timestep=fmt(TIMESTEP), integrator="implicit", cone="elliptic", impratio="10")
    sub(m, "size", njmax="4000", nconmax="1000")
    vis = sub(m, "visual")
    sub(vis, "global", offwidth=str(CAMERA_WIDTH), offheight=str(CAMERA_HEIGHT))
    sub(vis, "quality", shadowsize="2048")
    sub(vis, "map", znear="0.01", zfar="50")
    default = sub(m, "default")
    for name, attrs in CLASSES.items():
        d = sub(default, "default", {"class": name})
        sub(d, "geom", attrs)
    asset = sub(m, "asset")
    if floor:
        sub(
            asset,
            "texture",
            name="floor_grid",
            type="2d",
            builtin="checker",
            rgb1="0.82 0.82 0.80",
            rgb2="0.62 0.62 0.60",
            width="512",
            height="512",
            mark="edge",
            markrgb="0.3 0.3 0.3",
        )
        sub(
            asset,
            "material",
            name="floor",
            texture="floor_grid",
            texrepeat="10 10",
            reflectance="0",
        )
        sub(
            asset,
            "texture",
            name="sky",
            type="skybox",
            builtin="gradient",
            rgb1="0.75 0.82 0.9",
            rgb2="0.35 0.4 0.45",
            width="256",
            height="256",
        )
    meshes: dict = {}
    textures: dict = {}
    tag_meshes: dict = {}
    for p in parts:
        meshes.update(p.meshes)
        textures.update(p.textures)
        tag_meshes.update(p.tag_meshes)
    for name in sorted(meshes):
        file, scale = meshes[name]
        sub(
            asset,
            "mesh",
            name=name,
            file=file,
            scale=fmt_vec(scale) if tuple(scale) != (1.0, 1.0, 1.0) else None,
        )
    for name in sorted(tag_meshes):
        asset.append(tag_plate_mesh(name, tag_meshes[name]))
    for name in sorted(textures):
        sub(asset, "texture", name=name, type="2d", file=textures[name])
        sub(
            asset, "material", name=name, texture=name, specular="0", shininess="0", reflectance="0"
        )
    world = sub(m, "worldbody")
    if floor:
        sub(
            world,
            "geom",
            {
                "name": "floor",
                "class": "floor",
                "type": "plane",
                "size": "0 0 0.05",
                "material": "floor",
            },
        )
        sub(
            world,
            "light",
            name="sun",
            directional="true",
            pos="0 0 6",
            dir="0.3 0.2 -1",
            diffuse="0.6 0.6 0.6",
            specular="0.1 0.1 0.1",
            castshadow="true",
        )
        sub(
            world,
            "light",
            name="fill",
            directional="true",
            pos="0 0 6",
            dir="-0.3 -0.2 -1",
            diffuse="0.3 0.3 0.3",
            specular="0 0 0",
            castshadow="false",
        )
    for e in extra_world:
        world.append(e)
    for p in parts:
        for b in p.bodies:
            world.append(b)
    actuators = [a for p in parts for a in p.actuators]
    if actuators:
        act = sub(m, "actuator")
        act.extend(actuators)
    equalities = [e for p in parts for e in p.equalities]
    if equalities:
        sub(m, "equality").extend(equalities)
    sensors = [s for p in parts for s in p.sensors]
    if sensors:
        sen = sub(m, "sensor")
        sen.extend(sensors)
    qpos = [a for p in parts for a in p.qpos]
    ctrl = [a for p in parts for a in p.ctrl]
    mpos = [a for p in parts for a in p.mocap_pos]
    mquat = [a for p in parts for a in p.mocap_quat]
    if qpos:
        key = sub(sub(m, "keyframe"), "key", name=keyframe, qpos=fmt_vec(qpos))
        if ctrl:
            key.set("ctrl", fmt_vec(ctrl))
        if mpos:
            key.set("mpos", fmt_vec(mpos))
            key.set("mquat", fmt_vec(mquat))
    return m


def _set_pose(el: ET.Element, X: np.ndarray) -> None:
    if np.any(np.abs(X[:3, 3]) > 0):
        el.set("pos", fmt_vec(X[:3, 3]))
    q = matrix_to_quat_wxyz(X[:3, :3])
    if abs(q[0] - 1.0) > 1e-15:
        el.set("quat", fmt_vec(q))


def placement(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """X_WO of a body at (x, y, z) turned by ``yaw`` about the vertical."""
    c, s = np.cos(yaw), np.sin(yaw)
    return homogeneous(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), [x, y, z])
