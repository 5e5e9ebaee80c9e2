"""``marionette robot check DIR``: is a robot folder complete and consistent? Then its MJCF.

Every problem is one line that names the file, the key or element, and what to add or fix, so
that a user bringing a robot (docs/robots.md) fixes them in one pass. The checks, in order:

1. ``robot.yaml`` follows its schema (unknown keys with a "did you mean", types, ranges);
2. the URDF and the SRDF load in Pinocchio, the URDF through the robot's ``package://``
   search path (its meshes exist);
3. no joint has a link's name (Pinocchio frames are looked up by name); joints the URDF
   declares ``<mimic>`` are fixed (marionette drives their driver; MuJoCo moves them), and every
   actuated joint has an effort limit (its servo's force limit) and a servo entry in
   ``simulation.actuators``;
4. every link, frame and joint robot.yaml names exists (grippers, contact bodies, tags, feet,
   cameras, sensors, calibration, walking);
5. gripper joints: open and closed positions within the joint's limits, the gripper's link not
   moved by its own finger joint, the links it moves with collision geometry;
6. the reference posture exists in the SRDF, lies within the joint limits and is free of
   self-collision (the SRDF's disabled pairs apart);
7. collision meshes of hand links far from convex are noted (MuJoCo would collide their convex
   hull; the MJCF gives them as convex pieces);
8. the MJCF is generated (``<robot>.xml``, meshes linked or converted) and MuJoCo compiles it.

A URDF whose root link is ``world`` is accepted (its MuJoCo body is renamed; a note says so).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from marionette import robots
from marionette.schemas import DataFileError

from .urdf import MOVABLE, UrdfError, parse_urdf


@dataclass(frozen=True)
class Finding:
    """One problem (``error``: the robot cannot run) or remark (``note``) about a robot folder."""

    level: str  # "error" | "note"
    where: str  # file (and key)
    message: str

    def __str__(self) -> str:
        return f"{self.level}: {self.where}: {self.message}"


def check_robot(folder: str | Path, build: bool = True) -> list[Finding]:
    """The findings on the robot in ``folder``; with ``build`` and no error, its MJCF is written
    and compiled by MuJoCo."""
    folder = Path(folder)
    try:
        desc = robots.robot(folder)
    except robots.UnknownModel as e:  # its message may already start with the folder
        return [Finding("error", str(folder), str(e).removeprefix(f"{folder}: "))]
    except DataFileError as e:
        where, _, what = str(e).partition(": ")
        return [Finding("error", where, what)]
    out: list[Finding] = []
    yaml_file = str(desc.semantics)
    for path, key in ((desc.urdf, "urdf"), (desc.srdf, "srdf")):
        if not path.is_file():
            out.append(
                Finding("error", yaml_file, f"{key}: {path.name} does not exist in {folder}")
            )
    if out:
        return out
    if desc.meshes is not None:
        try:
            robots.resolve_package_uri(desc.meshes)
        except FileNotFoundError as e:
            out.append(Finding("error", f"{yaml_file}: meshes", str(e)))
    try:
        urdf = parse_urdf(desc.urdf.read_text())
        urdf_root = urdf.root
    except (ET.ParseError, UrdfError) as e:
        return [*out, Finding("error", str(desc.urdf), f"not a URDF marionette reads: {e}")]
    if urdf_root == "world":
        out.append(
            Finding(
                "note",
                str(desc.urdf),
                "the root link is 'world': its MuJoCo body is named "
                f"'{urdf.name}_world' (MuJoCo reserves 'world')",
            )
        )
    out += _joint_findings(desc, urdf)
    if any(f.level == "error" for f in out):
        return out
    try:
        model, geom = robots.load_pinocchio(folder)
    except (KeyError, ValueError, RuntimeError, OSError) as e:
        return [*out, Finding("error", str(desc.srdf), _one_line(e))]
    out += _name_findings(desc, model)
    out += _gripper_findings(desc, model, urdf)
    if any(f.level == "error" for f in out):
        return out
    out += _reference_findings(desc, model, geom)
    out += _hand_mesh_findings(desc, urdf)
    if build and not any(f.level == "error" for f in out):
        out += build_robot(folder)
    return out


NOT_COMPILED = "written; not compiled (no C++ build)"


def build_robot(folder: str | Path) -> list[Finding]:
    """Links ``<folder>/meshes``, writes the MJCF and compiles it with MuJoCo."""
    from .generate import link_robot_meshes, robot_mjcf
    from .mjcf import RobotModelError

    desc = robots.robot(folder)
    try:
        link_robot_meshes(desc)
        text = robot_mjcf(folder)
    except (RobotModelError, FileNotFoundError, FileExistsError, UrdfError, DataFileError) as e:
        return [Finding("error", str(desc.mjcf), _one_line(e))]
    desc.mjcf.write_text(text)
    try:
        from marionette._core import sim

        sim.MjScene(str(desc.mjcf))
    except ImportError:
        return [Finding("note", str(desc.mjcf), NOT_COMPILED)]
    except Exception as e:  # MuJoCo's compiler error, whatever its type
        return [Finding("error", str(desc.mjcf), f"MuJoCo refuses it: {_one_line(e)}")]
    return []


def _joint_findings(desc: robots.RobotDescription, urdf) -> list[Finding]:
    out = []
    where = str(desc.urdf)
    for j in urdf.joints.values():
        if j.name in urdf.links:
            out.append(
                Finding(
                    "error",
                    where,
                    f"joint {j.name!r} has the name of a link: rename the joint (Pinocchio makes "
                    "a frame of both, so a frame looked up by that name is ambiguous; `marionette "
                    "robot import` renames fixed ones)",
                )
            )
        if j.mimic is not None and j.type in MOVABLE:
            out.append(
                Finding(
                    "error",
                    where,
                    f'joint {j.name!r} mimics {j.mimic.joint!r} but is type="{j.type}": make it '
                    'type="fixed", keeping its <mimic> and <axis> (MuJoCo moves it with its '
                    "driver; `marionette robot import` does this)",
                )
            )
            continue
        if j.type == "continuous":
            out.append(
                Finding(
                    "error",
                    where,
                    f'joint {j.name!r} is continuous: make it type="revolute" with wide limits '
                    '(e.g. <limit lower="-12.566" upper="12.566" .../>; `marionette robot import` '
                    "does this): the controller maps 1-DoF joints by angle",
                )
            )
            continue
        if j.type not in MOVABLE:
            continue
        if not j.effort or j.effort <= 0:
            out.append(
                Finding(
                    "error",
                    where,
                    f"joint {j.name!r} has no positive <limit effort>: its servo needs a force "
                    "limit",
                )
            )
        if not any(j.name.startswith(a.joints) for a in desc.actuators):
            out.append(
                Finding(
                    "error",
                    f"{desc.semantics}: simulation/actuators",
                    f"no entry matches joint {j.name!r}: add one ({{joints: {j.name}, kp: ..., "
                    "kv: ...}} or a prefix of its name)",
                )
            )
    return out


def _name_findings(desc: robots.RobotDescription, model) -> list[Finding]:
    sem = robots.semantics(desc.directory)
    links = [
        *((f"grippers/{g.name}/link", g.link) for g in sem.grippers),
        *((f"tags/{t.id}/link", t.link) for t in sem.tags),
        *((f"contacts/{c.name}/link", c.link) for c in sem.contacts),
        *((f"feet/{f.name}/frame", f.frame) for f in desc.feet),
        *((f"cameras/{c.name}/frame", c.frame) for c in desc.cameras),
        *((f"range_finders/{r.name}/frame", r.frame) for r in desc.range_finders),
        *((f"force_torque_sensors/{n}/link", link) for n, link in desc.force_torque_sensors),
        *((("imu/link", desc.imu_link),) if desc.imu_link else ()),
        *((f"grippers/{g}/jaws", b) for g, bodies in desc.grip_bodies.items() for b in bodies),
        *(("simulation/hand_links", link) for link in desc.hand_links),
        *((f"calibration/arms/{a.side}/tagged_link", a.tagged_link) for a in desc.calibrated_arms),
        *(
            (("calibration/base_frame", desc.calibration_base_frame),)
            if desc.calibration_base_frame
            else ()
        ),
    ]
    joints = [
        *((f"grippers/{g.name}/joint", g.joint) for g in sem.grippers if g.joint),
        *((f"calibration/arms/{a.side}/joints", j) for a in desc.calibrated_arms for j in a.joints),
        *(("calibration/head_joints", j) for j in desc.calibration_head_joints),
        *(("walking/frozen_joints", j) for j in desc.walking.get("frozen_joints", ())),
    ]
    out = []
    for key, link in links:
        if not model.existBodyName(link) and not model.existFrame(link):
            out.append(
                Finding(
                    "error",
                    f"{desc.semantics}: {key}",
                    f"{link!r} is not a link of {desc.urdf.name}"
                    + _suggest(link, [f.name for f in model.frames]),
                )
            )
    for key, joint in joints:
        if not model.existJointName(joint):
            out.append(
                Finding(
                    "error",
                    f"{desc.semantics}: {key}",
                    f"{joint!r} is not a movable joint of {desc.urdf.name}"
                    + _suggest(joint, list(model.names)),
                )
            )
    for side, gripper in (desc.walking.get("hands") or {}).items():
        if gripper not in [g.name for g in sem.grippers]:
            out.append(
                Finding(
                    "error",
                    f"{desc.semantics}: walking/hands/{side}",
                    f"{gripper!r} is not a gripper of this robot",
                )
            )
    for arm in desc.calibrated_arms:
        if len(arm.sampling_box) != len(arm.joints):
            out.append(
                Finding(
                    "error",
                    f"{desc.semantics}: calibration/arms/{arm.side}/sampling_box",
                    f"{len(arm.sampling_box)} intervals for {len(arm.joints)} joints",
                )
            )
    return out


def _gripper_findings(desc: robots.RobotDescription, model, urdf) -> list[Finding]:
    out = []
    for g in robots.semantics(desc.directory).grippers:
        if g.joint is None or not model.existJointName(g.joint):
            continue
        finger = model.getJointId(g.joint)
        link = next((f for f in model.frames if f.name == g.link), None)
        if link is not None and finger in model.supports[link.parentJoint]:
            out.append(
                Finding(
                    "error",
                    f"{desc.semantics}: grippers/{g.name}/link",
                    f"{g.link!r} moves with the finger joint {g.joint!r}: the gripper frame would "
                    f"move as the gripper closes; put it in the link the fingers are mounted on "
                    f"({urdf.joints[g.joint].parent!r}) and set its pose there",
                )
            )
        moved = urdf.subtree(urdf.joints[g.joint].child)
        if not any(urdf.links[m].collisions for m in moved):
            out.append(
                Finding(
                    "error",
                    f"{desc.urdf}: link {moved[0]}",
                    f"no <collision> on the links finger joint {g.joint!r} moves "
                    f"({', '.join(moved)}): in MuJoCo the jaw passes through what it should "
                    "hold, and the planner cannot keep it clear; give the jaw convex pieces "
                    "(boxes from its visual mesh's bounds; docs/robots.md, section 3)",
                )
            )
        i = model.joints[model.getJointId(g.joint)].idx_q
        lo, hi = model.lowerPositionLimit[i], model.upperPositionLimit[i]
        for key, value in (
            ("open_position", g.open_position),
            ("closed_position", g.closed_position),
        ):
            if not lo < value < hi:
                where = "outside" if not lo <= value <= hi else "on"
                out.append(
                    Finding(
                        "error",
                        f"{desc.semantics}: grippers/{g.name}/{key}",
                        f"{value} is {where} {g.joint}'s limits [{lo:g}, {hi:g}]: put it a little "
                        "inside (a command on a limit leaves the limit task no room)",
                    )
                )
    return out


def _reference_findings(desc: robots.RobotDescription, model, geom) -> list[Finding]:
    import pinocchio as pin

    try:
        q = robots.reference_configuration(desc.directory, model)
    except (KeyError, ValueError) as e:
        return [Finding("error", f"{desc.srdf}", _one_line(e))]
    data, gdata = model.createData(), pin.GeometryData(geom)
    pin.computeCollisions(model, data, geom, gdata, q, False)
    hits = [
        (geom.geometryObjects[p.first].name, geom.geometryObjects[p.second].name)
        for p, r in zip(geom.collisionPairs, gdata.collisionResults)
        if r.isCollision()
    ]
    if hits:
        a, b = hits[0]
        return [
            Finding(
                "error",
                str(desc.srdf),
                f"the reference posture {desc.reference!r} has {a} and {b} in collision"
                f"{f' (and {len(hits) - 1} more pairs)' if len(hits) > 1 else ''}: change the "
                "group_state, or add <disable_collisions> for links that always touch",
            )
        ]
    if not np.all(np.isfinite(q)):
        return [Finding("error", str(desc.srdf), "the reference posture has non-finite values")]
    return []


def _hand_mesh_findings(desc: robots.RobotDescription, urdf) -> list[Finding]:
    """A note per collision mesh of a hand link (the links that touch objects in MuJoCo) that
    fills less than MIN_FILL of its convex hull: MuJoCo collides a mesh as its convex hull,
    which fills the gap between jaws or the inside of a hook, so the MJCF generator gives such a
    mesh as its convex pieces (:mod:`.convex_parts`)."""
    import trimesh

    from .convex_parts import MIN_FILL, hull_fill
    from .mjcf import hand_links

    hands = hand_links(desc, urdf)
    hands |= {b for bodies in desc.grip_bodies.values() for b in bodies}
    out = []
    for link in sorted(hands & set(urdf.links)):
        for geometry in urdf.links[link].collisions:
            if geometry.kind != "mesh":
                continue
            try:
                mesh = trimesh.load(robots.resolve_package_uri(geometry.filename), force="mesh")
            except (FileNotFoundError, ValueError):
                continue  # a missing mesh is the URDF check's finding
            fill = hull_fill(mesh)
            if fill < MIN_FILL:
                out.append(
                    Finding(
                        "note",
                        f"{desc.urdf}: link {link}",
                        f"collision mesh {Path(geometry.filename).name} fills {fill:.0%} of its "
                        "convex hull, which is what MuJoCo would collide with objects (closing "
                        "the gap between jaws): the MJCF gives it as convex pieces (CoACD, in "
                        "the robot folder's convex_meshes)",
                    )
                )
    return out


def _suggest(name: str, candidates: list[str]) -> str:
    import difflib

    close = difflib.get_close_matches(name, candidates, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__
