"""``marionette robot import URDF --name NAME``: a robot folder to start from (docs/robots.md).

It writes ``<out>/<name>.urdf``, ``<name>.srdf`` and a ``robot.yaml`` whose every value is a
guess the user then checks, and prints what to review. What it changes in the URDF, and why:

* a movable joint with ``<mimic>`` becomes ``type="fixed"`` (its ``<mimic>`` and ``<axis>``
  kept): marionette drives the joint it follows, MuJoCo moves both;
* a continuous joint becomes revolute within two turns each way (the controller maps 1-DoF
  joints by angle);
* a fixed joint named as a link gets ``_joint`` appended (a frame looked up by that name would
  be ambiguous in Pinocchio);
* mesh URIs that are plain paths are made absolute, so that the folder can live anywhere; the
  folder they share becomes robot.yaml's ``meshes`` (package:// URIs are kept as they are).

The SRDF is the given one (a reference ``group_state`` added if it has none), else a new one:
the reference posture is every joint at 0 clipped into its limits, and the disabled collision
pairs are those of adjacent links and of pairs in collision in >= 95 % of random postures.
The servo of each joint (``simulation.actuators``) gets kp = 50 x its effort limit per radian or
metre and kv = kp / 50: stiff enough to follow a 1 kHz controller, damped by MuJoCo's implicit
integrator. The gripper is the SRDF's ``end_effector`` parent link (or ``--gripper-link``), with
its first finger joint below it (or, when that link is a jaw moved by a joint the SRDF's arm
group leaves out, the link the jaw is mounted on, with that joint); its frame's pose is left at
the link's origin for the user to set (x along the approach, out of the palm).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from .jaw import closing_limit
from .srdf import disabled_collision_pairs, srdf_text
from .urdf import MOVABLE, Joint, Urdf, UrdfError, parse_urdf
from .xml_util import attribute, indent_and_serialize, sub

SERVO_STIFFNESS_PER_EFFORT = 50.0  # kp / effort limit [1/rad or 1/m]
SERVO_TIME_CONSTANT = 0.02  # kv / kp [s]
REFERENCE_STATE = "home"
CONTINUOUS_RANGE = 4 * np.pi  # [rad] limits given to a continuous joint
JAW_MAX_TURN = np.pi  # [rad] a revolute joint ending a chain and turning less is a jaw's
GRIPPER_LIMIT_MARGIN = 0.025  # open/closed positions this fraction of the range inside the limits


class RobotImportError(ValueError):
    """The source files cannot make a robot folder; the message says why."""


def import_robot(
    urdf_path: str | Path,
    name: str,
    out_dir: str | Path,
    srdf_path: str | Path | None = None,
    base: str = "fixed",
    gripper_link: str | None = None,
) -> list[str]:
    """Writes the robot folder ``out_dir``; returns what the user should review (one line each)."""
    urdf_path, out_dir = Path(urdf_path), Path(out_dir)
    if not urdf_path.is_file():
        raise RobotImportError(f"{urdf_path}: no such file")
    xacro = RobotImportError(
        f"{urdf_path}: a xacro file; expand it first (`xacro FILE > OUT.urdf`)"
    )
    if urdf_path.suffix == ".xacro":
        raise xacro
    if (out_dir / "robot.yaml").exists():
        raise RobotImportError(f"{out_dir / 'robot.yaml'} exists: import into a new folder")
    try:
        root = ET.fromstring(urdf_path.read_text())
    except ET.ParseError as e:
        if "unbound prefix" in str(e) and "<xacro:" in urdf_path.read_text():
            raise xacro from None
        raise RobotImportError(f"{urdf_path}: not XML ({e})") from None
    if _has_xacro(root):
        raise xacro
    notes: list[str] = []
    as_written = ET.tostring(root, encoding="unicode")  # mimic joints movable: the jaw guess
    notes += _fix_mimics(root)
    notes += _fix_continuous(root)
    notes += _rename_fixed_joints_named_as_links(root)
    link_notes, renamed_links = _rename_links_named_as_movable_joints(root)
    notes += link_notes
    meshes = _mesh_folder(root, urdf_path.parent)
    source = _as_package_uri(urdf_path)
    urdf_text = indent_and_serialize(root, f"imported from {source} by `marionette robot import`")
    try:
        urdf = parse_urdf(urdf_text)
        hand = parse_urdf(as_written)
    except UrdfError as e:
        raise RobotImportError(f"{urdf_path}: {e}") from None
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / f"{name}.urdf").write_text(urdf_text)
    srdf, state, end_effector = _srdf(urdf_text, urdf, name, srdf_path, base, notes, renamed_links)
    (out_dir / f"{name}.srdf").write_text(srdf)
    grippers = [] if gripper_link else _srdf_grippers(srdf, urdf, hand, name, srdf_path, notes)
    if not grippers:
        grippers = [_gripper(urdf, hand, name, gripper_link, end_effector, srdf, urdf_path, notes)]
    description = {
        "format": "marionette-robot 1",
        "name": name,
        "description": f"{urdf.name}, imported from {urdf_path.name}",
        "source": source,
        "urdf": f"{name}.urdf",
        "srdf": f"{name}.srdf",
        "mjcf": f"{name}.xml",
        **({"meshes": meshes} if meshes else {}),
        "base": base,
        "reference_posture": state,
        "grippers": grippers,
        "simulation": {"actuators": _actuators(urdf)},
    }
    header = (
        f"# {name}: imported by `marionette robot import`; review it (docs/robots.md), then run\n"
        f"# `marionette robot check {_shown(out_dir)}`. Format: "
        "python/marionette/schemas/robot.schema.json\n"
    )
    (out_dir / "robot.yaml").write_text(
        header + yaml.safe_dump(description, sort_keys=False, default_flow_style=None, width=100)
    )
    return notes


def _gripper(
    urdf: Urdf,
    hand: Urdf,
    name: str,
    gripper_link: str | None,
    end_effector: str | None,
    srdf: str,
    urdf_path: Path,
    notes: list[str],
) -> dict[str, object]:
    """The gripper on ``gripper_link`` (else the SRDF's end effector, else the deepest link),
    with its finger joint; its frame at the link's origin for the user to place."""
    deepest = gripper_link is None and end_effector is None
    gripper_link = gripper_link or end_effector or _deepest_link(urdf)
    if gripper_link not in urdf.links:
        raise RobotImportError(f"--gripper-link {gripper_link!r} is not a link of {urdf_path}")
    jaw = None
    if gripper_link == end_effector:
        jaw = _jaw_joint(urdf, gripper_link, srdf)
        why = (
            f"the SRDF's end effector {gripper_link} is moved by {{}}, which the SRDF's arm "
            "group leaves out"
        )
    elif deepest:
        jaw = _leaf_jaw(urdf, gripper_link)
        why = (
            f"the deepest link {gripper_link} is moved by {{}}, the chain's last movable joint, "
            f"of a jaw's range ({JAW_MAX_TURN:g} rad at most)"
        )
    if jaw is not None:
        notes.append(
            f"grippers[0]/link: {why.format(jaw.name)}: a jaw; the gripper is on {jaw.parent}, "
            f"the link the jaw is mounted on, with finger joint {jaw.name}"
        )
        gripper_link = jaw.parent
    gripper: dict[str, object] = {
        "name": f"{name}/gripper",
        "link": gripper_link,
        "pose": {"xyz": [0.0, 0.0, 0.0], "xyzw": [0.0, 0.0, 0.0, 1.0]},
        "clearance": 0.05,
    }
    finger = jaw or _finger_joint(urdf, gripper_link)
    gripper.update(_finger(hand, finger, urdf_path, notes, 0))
    notes.append(
        f"grippers[0]/pose: the gripper frame sits at {gripper_link}'s origin; place it between "
        "the fingertips, x along the approach (out of the palm), y along which the fingers close"
    )
    return gripper


def _finger(
    hand: Urdf, finger: Joint | None, urdf_path: Path, notes: list[str], k: int
) -> dict[str, object]:
    """The ``joint``, ``open_position`` and ``closed_position`` of gripper ``k`` whose finger
    joint is ``finger`` (none without one): which limit closes it is guessed from the geometry
    of ``hand`` (the URDF as written, its mimic joints movable; marionette.models.jaw), else
    the lower one."""
    if finger is None:
        return {}
    lower, upper = finger.lower, finger.upper
    if lower is None or upper is None:
        raise RobotImportError(
            f"{urdf_path}: finger joint {finger.name} (below {finger.parent}) has no "
            "<limit lower upper>: add its limits, or name another --gripper-link"
        )
    closing = closing_limit(hand, hand.joints[finger.name], GRIPPER_LIMIT_MARGIN)
    closed = closing.closed or "lower"
    inside = GRIPPER_LIMIT_MARGIN * (upper - lower)
    limits = {"lower": lower + inside, "upper": upper - inside}
    opened = "upper" if closed == "lower" else "lower"
    measured = ", ".join(f"{v * 1000:.1f} mm at its {lim}" for lim, v in closing.distance.items())
    why = (
        f"its surface lies nearer the rest of the hand there ({measured})"
        if closing.closed
        else f"the hand's geometry cannot tell ({measured or 'no geometry'})"
    )
    notes.append(
        f"grippers[{k}]: finger joint {finger.name}, closed near its {closed} limit "
        f"{getattr(finger, closed):g} ({why}), open near its {opened} limit "
        f"{getattr(finger, opened):g}: swap them if it closes the other way"
    )
    return {
        "joint": finger.name,
        "open_position": round(limits[opened], 6),
        "closed_position": round(limits[closed], 6),
    }


def _srdf_grippers(
    srdf: str,
    urdf: Urdf,
    hand: Urdf,
    name: str,
    srdf_path: str | Path | None,
    notes: list[str],
) -> list[dict[str, object]]:
    """The grippers an SRDF declares the way HPP reads them: ``<gripper name clearance>`` with
    one ``<link>``, a ``<position>`` (text "x y z qw qx qy qz", or attributes ``xyz`` and one of
    ``rpy``, ``wxyz``, ``xyzw``) in that link and optionally a ``<joint>`` (else the finger
    joint found beside the link)."""
    out: list[dict[str, object]] = []
    where = str(srdf_path)
    for k, g in enumerate(ET.fromstring(srdf).findall("gripper")):
        gname = attribute(g, "name", where, RobotImportError)
        links = g.findall("link")
        if len(links) != 1:
            raise RobotImportError(f"{where}: gripper {gname!r} needs exactly one <link>")
        link = attribute(links[0], "name", f"{where}: gripper {gname!r}", RobotImportError)
        if link not in urdf.links:
            raise RobotImportError(f"{where}: gripper {gname!r}: {link!r} is not a URDF link")
        xyz, xyzw = _hpp_position(g.find("position"), f"{where}: gripper {gname!r}")
        gripper: dict[str, object] = {
            "name": f"{name}/{gname}",
            "link": link,
            "pose": {"xyz": xyz, "xyzw": xyzw},
            "clearance": float(g.get("clearance", "0.05")),
        }
        joints = [j.get("name") for j in g.findall("joint")]
        finger = urdf.joints.get(str(joints[0])) if joints else _finger_joint(urdf, link)
        if joints and (finger is None or finger.type not in MOVABLE):
            raise RobotImportError(
                f"{where}: gripper {gname!r}: {joints[0]!r} is not a movable joint of the URDF"
            )
        gripper.update(_finger(hand, finger, Path(where), notes, k))
        notes.append(
            f"grippers[{k}]: the SRDF's gripper {gname!r} on {link}, its frame and clearance "
            "as the SRDF gives them"
            + ("" if finger else "; no finger joint: it holds what it touches (a tool)")
        )
        out.append(gripper)
    return out


def _hpp_position(position: ET.Element | None, where: str) -> tuple[list[float], list[float]]:
    """(xyz, xyzw) of an HPP SRDF ``<position>`` (the identity when there is none)."""
    if position is None:
        return [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]

    def numbers(text: str, n: int, what: str) -> np.ndarray:
        try:
            v = np.array([float(x) for x in text.split()])
        except ValueError:
            v = np.zeros(0)
        if len(v) != n:
            raise RobotImportError(f"{where}: <position> {what} needs {n} numbers: {text!r}")
        return v

    if (position.text or "").strip():
        v = numbers(position.text or "", 7, "text (x y z qw qx qy qz)")
        xyz, q = v[:3], np.r_[v[4:7], v[3]]
    else:
        xyz = numbers(position.get("xyz", "0 0 0"), 3, "xyz")
        given = [a for a in ("rpy", "wxyz", "xyzw") if position.get(a)]
        if len(given) > 1:
            raise RobotImportError(f"{where}: <position> has {given}: give one of them")
        if not given:
            q = np.array([0.0, 0.0, 0.0, 1.0])
        elif given[0] == "rpy":
            import pinocchio as pin

            R = pin.rpy.rpyToMatrix(*numbers(position.get("rpy", ""), 3, "rpy"))
            q = pin.Quaternion(R).coeffs()
        else:
            v = numbers(position.get(given[0], ""), 4, given[0])
            q = np.r_[v[1:], v[0]] if given[0] == "wxyz" else v
    q = q / np.linalg.norm(q)
    return [round(float(x), 12) for x in xyz], [round(float(x), 12) for x in q]


def _has_xacro(root: ET.Element) -> bool:
    """Whether a parsed URDF still holds xacro: an element of the xacro namespace or an
    unexpanded ``${...}`` / ``$(...)`` value (xacro left in comments does not count)."""
    return any(
        (e.tag.startswith("{") and "xacro" in e.tag.split("}", 1)[0])
        or any("${" in v or "$(" in v for v in e.attrib.values())
        for e in root.iter()
    )


def _as_package_uri(path: Path) -> str:
    """``path`` as a ``package://`` URI when it lies in a package folder, else as given."""
    from marionette.robots import package_dirs

    resolved = path.resolve()
    for d in package_dirs():
        try:
            return f"package://{resolved.relative_to(Path(d).resolve()).as_posix()}"
        except ValueError:
            continue
    return str(path)


def _shown(path: Path) -> str:
    """``path`` relative to the working directory when it is below it."""
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


def _fix_mimics(root: ET.Element) -> list[str]:
    notes = []
    for j in root.findall("joint"):
        mimic = j.find("mimic")
        if mimic is not None and j.get("type") in MOVABLE:
            name = attribute(j, "name", "URDF", RobotImportError)
            driver = attribute(mimic, "joint", f"joint {name}", RobotImportError)
            notes.append(
                f"{name}: made fixed (it mimics {driver}; MuJoCo moves it with its driver)"
            )
            j.set("type", "fixed")
    return notes


def _rename_fixed_joints_named_as_links(root: ET.Element) -> list[str]:
    """A fixed joint named as a link gets ``_joint`` appended: Pinocchio makes a frame of both,
    and a frame looked up by that name (a gripper's link) would be ambiguous. A fixed joint's
    name is nowhere else in a robot folder; a movable one's is (SRDF, robot.yaml): the check
    reports those."""
    links = {link.get("name") for link in root.findall("link")}
    names = links | {j.get("name") for j in root.findall("joint")}
    notes = []
    for j in root.findall("joint"):
        name = j.get("name")
        if j.get("type") == "fixed" and name in links:
            new = next(n for k in range(100) if (n := f"{name}_joint{k or ''}") not in names)
            j.set("name", new)
            names.add(new)
            notes.append(f"{name}: a fixed joint named as a link, renamed {new}")
    return notes


def _rename_links_named_as_movable_joints(root: ET.Element) -> tuple[list[str], dict[str, str]]:
    """A link named as a movable joint gets ``_link`` appended (the joint keeps its name: it names
    a servo, the SRDF's postures and the robot's logs; a link's name only names a frame).
    Pinocchio makes a frame of both; a frame looked up by that name would be ambiguous.
    Returns the notes and the old -> new link names (the given SRDF's are renamed the same)."""
    links = {link.get("name") for link in root.findall("link")}
    names = links | {j.get("name") for j in root.findall("joint")}
    movable = {j.get("name") for j in root.findall("joint") if j.get("type") != "fixed"}
    renamed: dict[str, str] = {}
    for link in root.findall("link"):
        name = link.get("name")
        if name is not None and name in movable:
            new = next(n for k in range(100) if (n := f"{name}_link{k or ''}") not in names)
            link.set("name", new)
            names.add(new)
            renamed[name] = new
    for j in root.findall("joint"):
        for end in (j.find("parent"), j.find("child")):
            old_name = end.get("link") if end is not None else None
            if end is not None and old_name is not None and old_name in renamed:
                end.set("link", renamed[old_name])
    notes = [
        f"{old}: a link named as a movable joint, renamed {new} (the joint keeps its name)"
        for old, new in renamed.items()
    ]
    return notes, renamed


def _rename_srdf_links(sroot: ET.Element, renamed: dict[str, str]) -> bool:
    """Renames the links of an SRDF (collision pairs, groups' and grippers' links, end
    effectors) as ``renamed`` says; whether any was."""
    changed = False
    for element in sroot.iter():
        keys = ("link1", "link2", "parent_link") + (("name",) if element.tag == "link" else ())
        for key in keys:
            value = element.get(key)
            if value is not None and value in renamed:
                element.set(key, renamed[value])
                changed = True
    return changed


def _fix_continuous(root: ET.Element) -> list[str]:
    """Continuous joints become revolute joints of two turns each way: the controller and MuJoCo
    map 1-DoF joints with an angle, not Pinocchio's (cos, sin) of a continuous joint."""
    notes = []
    for j in root.findall("joint"):
        if j.get("type") != "continuous":
            continue
        j.set("type", "revolute")
        limit = j.find("limit")
        if limit is None:
            limit = ET.SubElement(j, "limit", effort="1", velocity="1")
        limit.set("lower", f"{-CONTINUOUS_RANGE:.6f}")
        limit.set("upper", f"{CONTINUOUS_RANGE:.6f}")
        notes.append(
            f"{j.get('name')}: continuous, made revolute within +-{CONTINUOUS_RANGE:.4f} rad "
            "(two turns each way)"
        )
    return notes


def _mesh_folder(root: ET.Element, urdf_dir: Path) -> str | None:
    """Make plain mesh paths absolute; return the folder every mesh URI shares (None: no mesh)."""
    uris = []
    for mesh in root.iter("mesh"):
        uri = mesh.get("filename", "")
        if uri and not uri.startswith("package://"):
            path = Path(uri.removeprefix("file://"))
            uri = str(path if path.is_absolute() else (urdf_dir / path).resolve())
            mesh.set("filename", uri)
        uris.append(uri)
    if not uris:
        return None
    packaged = [u.startswith("package://") for u in uris]
    if any(packaged) and not all(packaged):
        raise RobotImportError("the URDF mixes package:// mesh URIs and plain paths: use one kind")
    common = os.path.commonpath([os.path.dirname(u.removeprefix("package://")) for u in uris])
    return f"package://{common}" if packaged[0] else common


def _srdf(
    urdf_text: str,
    urdf: Urdf,
    name: str,
    srdf_path: str | Path | None,
    base: str,
    notes: list[str],
    renamed_links: dict[str, str] | None = None,
) -> tuple[str, str, str | None]:
    """(SRDF text, reference state name, end-effector parent link or None). ``renamed_links``:
    old -> new names of the URDF's links the import renamed, renamed in the given SRDF too."""
    end_effector = None
    if srdf_path is not None:
        srdf_path = Path(srdf_path)
        if not srdf_path.is_file():
            raise RobotImportError(f"{srdf_path}: no such file")
        text = srdf_path.read_text()
        try:
            sroot = ET.fromstring(text)
        except ET.ParseError as e:
            raise RobotImportError(f"{srdf_path}: not XML ({e})") from None
        where = str(srdf_path)
        if renamed_links and _rename_srdf_links(sroot, renamed_links):
            text = indent_and_serialize(sroot, "its links renamed as in the URDF")
        ee = sroot.find("end_effector")
        end_effector = ee.get("parent_link") if ee is not None else None
        pairs = [
            (
                attribute(d, "link1", where, RobotImportError),
                attribute(d, "link2", where, RobotImportError),
                d.get("reason") or "",
            )
            for d in sroot.findall("disable_collisions")
        ]
        known = {tuple(sorted(p[:2])) for p in pairs}
        missing = [
            p for p in disabled_collision_pairs(urdf_text) if tuple(sorted(p[:2])) not in known
        ]
        for a, b, reason in missing:  # adjacent or always touching: the SRDF forgot them
            sub(sroot, "disable_collisions", link1=a, link2=b, reason=reason)
        if missing:
            notes.append(
                f"SRDF: {len(missing)} collision pairs it lacked (adjacent or always in contact) "
                "disabled"
            )
            text = indent_and_serialize(sroot, "with the collision pairs it lacked disabled")
        states = [
            attribute(g, "name", where, RobotImportError) for g in sroot.findall("group_state")
        ]
        collides = _self_collision(urdf_text, pairs + missing)
        refused = {}
        for state in states:
            problem = _state_problem(urdf_text, text, state, collides)
            if problem is None:
                notes.append(f"reference posture: the SRDF's group_state {state!r}")
                return text, state, end_effector
            refused[state] = problem
        posture, _ = _collision_free_posture(urdf_text, _zero_posture(urdf), pairs + missing)
        added = next(
            s
            for k in range(len(states) + 1)
            if (s := REFERENCE_STATE + (f"_{k}" if k else "")) not in states
        )
        gs = sub(sroot, "group_state", name=added, group="all")
        for joint, value in posture.items():
            sub(gs, "joint", name=joint, value=f"{value:.12g}")
        why = "; ".join(f"{s}: {p}" for s, p in refused.items()) or "it has none"
        notes.append(
            f"reference posture: added {added!r} (collision-free, around every joint at 0) "
            f"because no SRDF group_state fits ({why}); edit it to a natural one"
        )
        text = indent_and_serialize(sroot, "with a reference group_state added")
        return text, added, end_effector
    pairs = disabled_collision_pairs(urdf_text)
    posture, tries = _collision_free_posture(urdf_text, _zero_posture(urdf), pairs)
    how = (
        "every joint at 0 within its limits"
        if tries == 0
        else f"the first collision-free of {tries + 1} postures drawn around every joint at 0"
    )
    notes.append(
        f"SRDF: written with the reference posture {REFERENCE_STATE!r} ({how}) and "
        f"{len(pairs)} disabled collision pairs; edit the posture to a natural one"
    )
    text = srdf_text(
        name,
        REFERENCE_STATE,
        posture,
        pairs,
        "written by `marionette robot import`",
        root_joint="0 0 1 0" if base == "planar" else None,
    )
    return text, REFERENCE_STATE, end_effector


def _collision_free_posture(
    urdf_text: str,
    posture: dict[str, float],
    pairs: list[tuple[str, str, str]],
    draws: int = 400,
    seed: int = 0,
) -> tuple[dict[str, float], int]:
    """``posture`` when the robot is free of self-collision there (the ``pairs`` skipped), else
    the first collision-free posture drawn around it, farther and farther (up to the joint
    limits); (posture, draws it took). Raises RobotImportError when none is found."""
    import pinocchio as pin

    model = pin.buildModelFromXML(urdf_text)
    collides = _self_collision(urdf_text, pairs)
    names = [n for n in posture if model.existJointName(n)]
    idx = [model.joints[model.getJointId(n)].idx_q for n in names]
    lo, hi = model.lowerPositionLimit[idx], model.upperPositionLimit[idx]
    lo, hi = np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)
    center = np.array([posture[n] for n in names])
    rng = np.random.default_rng(seed)
    for k in range(draws + 1):
        spread = k / draws
        values = (
            np.clip(center + spread * (rng.random(len(idx)) * (hi - lo) - (center - lo)), lo, hi)
            if k
            else center
        )
        q = pin.neutral(model)
        q[idx] = values
        if collides(q) is None:
            return dict(zip(names, (float(v) for v in values))), k
    raise RobotImportError(
        f"no posture free of self-collision found in {draws} draws: give an SRDF with a group_state"
    )


def _state_problem(
    urdf_text: str, srdf: str, state: str, collides: Callable[[np.ndarray], str | None]
) -> str | None:
    """Why ``state`` cannot be the reference posture (a joint unknown or outside its limits,
    links in collision), or None."""
    import pinocchio as pin

    from marionette.models.semantics import Semantics
    from marionette.robots import configuration_from_srdf

    model = pin.buildModelFromXML(urdf_text)
    try:
        q = configuration_from_srdf(model, srdf, state, Semantics(model.name))
    except (KeyError, ValueError) as e:
        return str(e.args[0] if e.args else e).split(": ", 1)[-1]
    return collides(q)


def _self_collision(
    urdf_text: str, pairs: list[tuple[str, str, str]]
) -> Callable[[np.ndarray], str | None]:
    """A test of configurations of the URDF's Pinocchio model: None when free of self-collision
    (the link ``pairs`` skipped), else which links collide."""
    import pinocchio as pin

    from marionette.robots import package_dirs

    model = pin.buildModelFromXML(urdf_text)
    geom = pin.buildGeomFromUrdfString(
        model, urdf_text, pin.GeometryType.COLLISION, None, package_dirs()
    )
    geom.addAllCollisionPairs()
    link_of = [model.frames[g.parentFrame].name for g in geom.geometryObjects]
    skip = {tuple(sorted(p[:2])) for p in pairs}
    for k in reversed(range(len(geom.collisionPairs))):
        cp = geom.collisionPairs[k]
        if tuple(sorted((link_of[cp.first], link_of[cp.second]))) in skip:
            geom.removeCollisionPair(cp)
    data, gdata = model.createData(), pin.GeometryData(geom)

    def collides(q: np.ndarray) -> str | None:
        if not pin.computeCollisions(model, data, geom, gdata, q, False):
            return None
        hits = sorted(
            {
                tuple(sorted((link_of[p.first], link_of[p.second])))
                for p, r in zip(geom.collisionPairs, gdata.collisionResults)
                if r.isCollision()
            }
        )
        return "links in collision: " + ", ".join(f"{a} and {b}" for a, b in hits)

    return collides


def _zero_posture(urdf: Urdf) -> dict[str, float]:
    out = {}
    for j in urdf.joints.values():
        if j.type in ("revolute", "prismatic") and j.mimic is None:
            lo = -np.inf if j.lower is None else j.lower
            hi = np.inf if j.upper is None else j.upper
            out[j.name] = float(np.clip(0.0, lo, hi))
    return out


def _finger_joint(urdf: Urdf, gripper_link: str) -> Joint | None:
    """The first movable joint (not a mimic) off the chain from the root to ``gripper_link``, in
    the subtree of that chain's last two links (a hand's fingers beside its tool frame), or None."""
    chain: list[Joint] = []
    link = gripper_link
    while (j := urdf.parent_joint(link)) is not None:
        chain.append(j)
        link = j.parent
    on_chain = {j.name for j in chain}
    for j in chain[:3]:  # the gripper link, its parent, its grandparent
        for other in urdf.subtree(j.parent):
            for k in urdf.child_joints(other):
                if k.type in MOVABLE and k.mimic is None and k.name not in on_chain:
                    return k
    return None


def _jaw_joint(urdf: Urdf, link: str, srdf: str) -> Joint | None:
    """The joint moving ``link`` when it is a jaw, else None: a movable joint (not a mimic) that
    the SRDF groups naming the other movable joints of the chain to ``link`` (the arm) leave
    out. An SRDF may name a moving jaw as its end effector; a gripper frame there would move
    as the gripper closes."""
    joint = urdf.parent_joint(link)
    if joint is None or joint.type not in MOVABLE or joint.mimic is not None:
        return None
    chain = set()
    parent = urdf.parent_joint(joint.parent)
    while parent is not None:
        if parent.type in MOVABLE:
            chain.add(parent.name)
        parent = urdf.parent_joint(parent.parent)
    groups = [
        {j.get("name") for j in g.findall("joint")} for g in ET.fromstring(srdf).iter("group")
    ]
    arm = [g for g in groups if g & chain]
    return joint if arm and not any(joint.name in g for g in arm) else None


def _leaf_jaw(urdf: Urdf, link: str) -> Joint | None:
    """The joint moving ``link`` when, without an SRDF to tell, it looks like a jaw, else None:
    the last movable joint (not a mimic) of the chain to ``link``, below another movable one (an
    arm), sliding or turning less than JAW_MAX_TURN (a jaw closes within half a turn; an arm's
    last joint, a wrist, turns a full one or more). A gripper frame on a jaw would move as the
    gripper closes; it belongs on the link the jaw is mounted on."""
    joint = urdf.parent_joint(link)
    if joint is None or joint.type not in MOVABLE or joint.mimic is not None:
        return None
    if any(k.type in MOVABLE for below in urdf.subtree(link) for k in urdf.child_joints(below)):
        return None
    parent = urdf.parent_joint(joint.parent)
    while parent is not None and parent.type not in MOVABLE:
        parent = urdf.parent_joint(parent.parent)
    if parent is None or joint.lower is None or joint.upper is None:
        return None
    if joint.type == "revolute" and joint.upper - joint.lower >= JAW_MAX_TURN:
        return None
    return joint


def _deepest_link(urdf: Urdf) -> str:
    depth = {urdf.root: 0}
    order = [urdf.root]
    for link in order:
        for j in urdf.child_joints(link):
            depth[j.child] = depth[link] + 1
            order.append(j.child)
    return max(order, key=lambda link: depth[link])


def _actuators(urdf: Urdf) -> list[dict[str, object]]:
    out = []
    for j in urdf.joints.values():
        if j.type not in MOVABLE or j.mimic is not None:
            continue
        effort = j.effort if j.effort and j.effort > 0 else 1.0
        kp = SERVO_STIFFNESS_PER_EFFORT * effort
        out.append(
            {
                "joints": j.name,
                "kp": round(kp, 3),
                "kv": round(kp * SERVO_TIME_CONSTANT, 3),
                "armature": 0.01,
            }
        )
    return out
