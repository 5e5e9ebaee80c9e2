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
from dataclasses import dataclass, field

import numpy as np

from marionette.robots import mujoco_layout, pinocchio_to_mujoco, robot

from . import apriltag
from .objects import ObjectSpec
from .robot_models import (
    MOVING_MIMICS,
    PLANAR_BASE,
    SOLE_BOX_THICKNESS,
    TALOS_SOLE,
    hand_links,
    parsed_urdf,
    robot_semantics,
    servo_gains,
)
from .semantics import Semantics
from .urdf import mimic_equality, parse_urdf, urdf_to_mjcf
from .xml_util import fmt, fmt_vec, homogeneous, matrix_to_quat_wxyz, sub

TIMESTEP = 0.001
CAMERA_WIDTH, CAMERA_HEIGHT = 640, 480
# Orbbec Astra (TALOS) and Asus Xtion (TIAGo) RGB: about 45 deg vertical field of view,
# fy = 240 / tan(22.5 deg) = 579.4 px at 640 x 480.
CAMERA_FOVY_DEG = 45.0
TAG_THICKNESS = 0.001  # [m] the tag plate sinks this deep below its printed face
TAG_PIXELS_PER_CELL = 16

CLASSES = {
    "floor": dict(contype="1", conaffinity="20"),
    "robot_body": dict(contype="2", conaffinity="0"),
    # Stiffer than MuJoCo's default contact (time constant 4 ms instead of 20 ms, critically
    # damped): TALOS' soles sink 0.3 mm instead of 0.65 mm into the floor.
    "robot_sole": dict(
        contype="4",
        conaffinity="49",
        friction="1 0.005 0.0001",
        solref="0.004 1",
        rgba="0.2 0.2 0.2 1",
    ),
    "robot_hand": dict(contype="8", conaffinity="48", friction="1 0.005 0.0001"),
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


def robot_part(name: str, q_reference: np.ndarray, X_WB: np.ndarray | None = None) -> Part:
    """Robot ``name`` with its base at X_WB (fixed bases) or its reference configuration."""
    desc = robot(name)
    urdf = parsed_urdf(name)
    hands = hand_links(name, urdf)
    mesh_root = f"{robot(name).meshes}/"

    def mesh_file(uri: str) -> str:
        rel = uri.removeprefix("package://example-robot-data/robots/")
        if not rel.startswith(mesh_root):
            raise ValueError(f"{name}: mesh {uri} outside {mesh_root}")
        return f"{name}/meshes/{rel.removeprefix(mesh_root)}"

    def geom_class(link: str) -> str:
        return "robot_hand" if link in hands else "robot_body"

    def armature(joint) -> float:
        return servo_gains(name, joint.name).armature

    # The URDF's mimic joints (the UR10 gripper's second finger) move in MuJoCo, tied to their
    # driver by equalities, so a closing gripper really squeezes; the controller's model keeps
    # them fixed (MOVING_MIMICS says why TALOS' stay fixed).
    tree = urdf_to_mjcf(
        urdf, mesh_file, f"{name}/", geom_class, armature, mimics=name in MOVING_MIMICS
    )
    part = Part(meshes=dict(tree.meshes), equalities=[mimic_equality(j) for j in tree.mimics])
    root = tree.root
    if desc.base == "free_flyer":
        root.insert(0, ET.Element("freejoint", name="root_joint"))
    elif desc.base == "planar":
        for i, (jname, kind, axis, _) in enumerate(PLANAR_BASE):
            g = servo_gains(name, jname)
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
    sem = robot_semantics(name)
    _add_gripper_sites(tree.bodies, sem)
    if name == "talos":
        _talos_extras(tree.bodies, part)
    if name in ("tiago", "ur10"):
        _wrist_ft_sensor(tree.bodies, part, {"tiago": "wrist_ft_link", "ur10": "tool0"}[name])
    for tag in sem.tags:
        _add_tag(tree.bodies[tag.link], tag.id, tag.family, tag.size, tag.pose.matrix(), part)
    if desc.camera_frame:
        cam = sub(
            tree.bodies[desc.camera_frame],
            "camera",
            name=desc.camera,
            mode="fixed",
            fovy=fmt(CAMERA_FOVY_DEG),
        )
        # Optical frame: z along the view, y down. MuJoCo camera: looks along -z, y up.
        cam.set("quat", "0 1 0 0")
    # Actuators: the planar base first, then every URDF joint in MJCF (= Pinocchio) order.
    joints = (
        [(j, "slide" if k == "slide" else "hinge", None, None, f) for j, k, _, f in PLANAR_BASE]
        if desc.base == "planar"
        else []
    )
    joints += [(j.name, j.type, j.lower, j.upper, j.effort) for j in tree.joints]
    for jname, _, lo, hi, effort in joints:
        g = servo_gains(name, jname)
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
                        if lo is not None
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


def _add_gripper_sites(bodies: dict[str, ET.Element], sem: Semantics) -> None:
    for g in sem.grippers:
        site = sub(
            bodies[g.link], "site", name=g.name, size="0.01", group=SITE_GROUP, rgba="0 0.8 0 1"
        )
        _set_pose(site, g.pose.matrix())


def _talos_extras(bodies: dict[str, ET.Element], part: Part) -> None:
    lx, ly = TALOS_SOLE[0] / 2, TALOS_SOLE[1] / 2
    h = SOLE_BOX_THICKNESS / 2
    for side in ("left", "right"):
        body = bodies[f"{side}_sole_link"]
        # Bottom face on the sole plane z = 0 of the sole link.
        sub(
            body,
            "geom",
            {
                "name": f"{side}_sole",
                "class": "robot_sole",
                "type": "box",
                "size": fmt_vec([lx, ly, h]),
                "pos": fmt_vec([0, 0, h]),
            },
        )
        sub(body, "site", name=f"{side}_sole", size="0.01", group=SITE_GROUP)
        part.sensors.append(ET.Element("force", name=f"{side}_sole_force", site=f"{side}_sole"))
        part.sensors.append(ET.Element("torque", name=f"{side}_sole_torque", site=f"{side}_sole"))
    for side in ("left", "right"):
        sub(
            bodies[f"wrist_{side}_ft_link"],
            "site",
            name=f"{side}_wrist_ft",
            size="0.01",
            group=SITE_GROUP,
        )
        part.sensors.append(
            ET.Element("force", name=f"{side}_wrist_force", site=f"{side}_wrist_ft")
        )
        part.sensors.append(
            ET.Element("torque", name=f"{side}_wrist_torque", site=f"{side}_wrist_ft")
        )
    sub(bodies["imu_link"], "site", name="imu", size="0.01", group=SITE_GROUP)
    part.sensors += [
        ET.Element("gyro", name="imu_gyro", site="imu"),
        ET.Element("accelerometer", name="imu_accelerometer", site="imu"),
        ET.Element("framequat", name="imu_orientation", objtype="site", objname="imu"),
    ]


def _wrist_ft_sensor(bodies: dict[str, ET.Element], part: Part, link: str) -> None:
    sub(bodies[link], "site", name="wrist_ft", size="0.01", group=SITE_GROUP)
    part.sensors += [
        ET.Element("force", name="wrist_force", site="wrist_ft"),
        ET.Element("torque", name="wrist_torque", site="wrist_ft"),
    ]


# --- objects -----------------------------------------------------------------------------------


def object_part(spec: ObjectSpec, instance: str, X_WO: np.ndarray) -> Part:
    """Object ``spec`` as body ``instance`` at X_WO: a free body or a mocap body."""
    urdf = parse_urdf(spec.urdf())
    cls = "object" if spec.sim == "free" else "fixture"
    tree = urdf_to_mjcf(urdf, lambda uri: uri, f"{instance}/", lambda link: cls, visuals=True)
    body = tree.root
    body.set("name", instance)
    _set_pose(body, X_WO)
    part = Part()
    if spec.sim == "free":
        body.insert(0, ET.Element("freejoint", name=instance))
        q = matrix_to_quat_wxyz(X_WO[:3, :3])
        part.qpos = [*X_WO[:3, 3], *q]
    else:
        body.set("mocap", "true")
        part.mocap_pos = list(X_WO[:3, 3])
        part.mocap_quat = list(matrix_to_quat_wxyz(X_WO[:3, :3]))
    sem = spec.semantics()
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
    extra_world: list[ET.Element] = (),
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
    # Elliptic friction cones with impratio 10: feet and held objects creep 5x less (TALOS
    # standing: 0.1 mm in 5 s instead of 0.5 mm).
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
