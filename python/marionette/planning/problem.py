"""Manipulation problem: robots, objects and environment in one Pinocchio configuration space.

Thesis §3.2.1: CS = CS_robot1 x ... x CS_object1 x ...  Every model is loaded from URDF with its
names prefixed ``<name>/`` (as HPP does), robots first, then free-flying objects, then the fixed
environment, so q = (q_robots, q_objects) and the layout is the one HPP uses.  Grippers, handles
and contact surfaces are read from HPP-style SRDF tags (``<gripper>``, ``<handle>``,
``<contact>``) or given inline in the problem YAML; they become Pinocchio frames of the model.

A problem file (YAML) names the models and the query; see ``bench/ur5_box/problem.yaml``.
"""

from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from marionette.schemas import DataFileError, read_yaml


class ProblemError(ValueError):
    """A problem description that cannot be built (missing file, unknown name, bad value)."""


@dataclasses.dataclass(frozen=True)
class Gripper:
    """A gripper frame (HPP: the point that grasps). Its x axis is the approach axis.

    ``frame_id`` is a Pinocchio frame of the problem model; ``clearance`` [m] is the gripper's
    share of the pre-grasp distance.
    """

    name: str
    frame_id: int
    joint_id: int
    clearance: float


@dataclasses.dataclass(frozen=True)
class Handle:
    """A handle frame on an object (HPP). Grasp: gripper frame == handle frame on the ``mask`` rows.

    ``mask`` selects rows of the (translation, rotation) error; a handle symmetric about its
    approach axis x leaves rotation about x free: mask (1,1,1,0,1,1).  ``approach`` is the unit
    approach axis in the handle frame (HPP: x); the pre-grasp puts the gripper
    ``clearance + gripper.clearance`` metres back along it.
    """

    name: str
    object: str
    frame_id: int
    joint_id: int
    clearance: float
    mask: tuple[bool, ...] = (True,) * 6
    approach: tuple[float, float, float] = (1.0, 0.0, 0.0)


@dataclasses.dataclass(frozen=True)
class ContactSurface:
    """A planar convex polygon on a body: placements put an object surface on an environment one.

    ``M_JS``: pose of the surface frame S in its joint's frame; S's origin is the polygon
    centroid and its z axis the outward normal (points given counter-clockwise seen from
    outside, as HPP's ``<contact>``).  ``polygon_S`` (k x 2): vertices in S's xy plane.
    ``owner`` is the object name, or None for the environment.
    """

    name: str
    owner: str | None
    joint_id: int
    M_JS: pin.SE3
    polygon_S: np.ndarray


@dataclasses.dataclass(frozen=True)
class ObjectInfo:
    """A free-flying object: its root joint and index ranges in q (7) and v (6)."""

    name: str
    joint_id: int
    idx_q: int
    idx_v: int
    handles: tuple[str, ...]
    contacts: tuple[str, ...]


@dataclasses.dataclass(frozen=True)
class ModelSource:
    """One model of the problem as loaded: name (prefix), URDF file, root joint ("fixed" or
    "freeflyer"), placement in the world, and its grippers / handles / contacts / disabled
    collision pairs in link frames (what an HPP SRDF of it says; bench/hpp_side.py)."""

    name: str
    urdf: Path
    root: str
    pose: pin.SE3
    grippers: tuple[tuple[str, str, pin.SE3, float], ...]
    handles: tuple[tuple[str, str, pin.SE3, float, tuple[bool, ...], tuple[float, ...]], ...]
    contacts: tuple[tuple[str, str, np.ndarray], ...]
    disabled: tuple[tuple[str, str], ...]


@dataclasses.dataclass
class ManipulationProblem:
    """Model + data layout of a manipulation problem; immutable after :func:`load_problem`.

    ``model``/``geom_model``: the combined Pinocchio models; ``lower``/``upper`` (nq): sampling
    bounds (quaternion components are not bounded); ``q_init``/``q_goal`` (nq), None when the
    file gives none (a problem used only to build its graph).
    """

    name: str
    model: pin.Model
    geom_model: pin.GeometryModel
    grippers: dict[str, Gripper]
    handles: dict[str, Handle]
    contacts: dict[str, ContactSurface]
    objects: dict[str, ObjectInfo]
    environment_contacts: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    q_init: np.ndarray | None
    q_goal: np.ndarray | None
    robot_names: tuple[str, ...]
    settings: dict[str, Any]
    source: Path | None = None
    robot_joint_ids: tuple[int, ...] = ()
    freeflyer_idx_q: tuple[int, ...] = ()
    fixed_rotation_idx_q: tuple[int, ...] = ()  # free-flyers sampled with their init rotation
    models: tuple[ModelSource, ...] = ()  # what each model was built from, in q order

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    def require_init(self) -> np.ndarray:
        """``q_init``; raises ProblemError when the problem file gives no ``init``."""
        if self.q_init is None:
            raise ProblemError(f"problem '{self.name}' needs an 'init' configuration")
        return self.q_init

    def require_goal(self) -> np.ndarray:
        """``q_goal``; raises ProblemError when the problem file gives no ``goal``."""
        if self.q_goal is None:
            raise ProblemError(f"problem '{self.name}' needs a 'goal' configuration")
        return self.q_goal

    def create_data(self) -> tuple[pin.Data, pin.GeometryData]:
        """Fresh (Data, GeometryData) for one thread of computation (Model/Data split)."""
        return self.model.createData(), pin.GeometryData(self.geom_model)

    def frame_id(self, name: str) -> int:
        if not self.model.existFrame(name):
            raise ProblemError(f"no frame '{name}' in problem '{self.name}'")
        return self.model.getFrameId(name)

    def joint_names(self) -> list[str]:
        return list(self.model.names)[1:]

    def configuration_layout(self) -> list[str]:
        """One label per q entry: joint names, and '<joint>.x' ... '<joint>.qw' for free-flyers."""
        return _layout(self.model)


def _layout(model: pin.Model) -> list[str]:
    labels: list[str] = []
    for jid in range(1, model.njoints):
        j = model.joints[jid]
        name = model.names[jid]
        if j.nq == 1:
            labels.append(name)
        elif j.nq == 7:
            labels += [f"{name}.{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
        else:
            labels += [f"{name}[{i}]" for i in range(j.nq)]
    return labels


# ---------------------------------------------------------------------------------------------
# Loading


def _resolve(path: str, base: Path) -> Path:
    """``package://<package>/<file>`` through the package search path (:func:`_package_dirs`),
    or a path relative to the problem file."""
    if path.startswith("package://"):
        rest = path[len("package://") :]
        package = rest.partition("/")[0]
        for root in _package_dirs():
            candidate = Path(root) / rest
            if candidate.exists():
                return candidate
        raise ProblemError(
            f"cannot resolve {path}: package '{package}' not found in the package search path "
            f"{_package_dirs()} (add its parent folder to ROS_PACKAGE_PATH)"
        )
    p = Path(path)
    if not p.is_absolute():
        p = base / p
    if not p.exists():
        raise ProblemError(f"file not found: {p}")
    return p


def _package_dirs() -> list[str]:
    """Folders where ``package://<package>/...`` URIs resolve (as ``<folder>/<package>/...``), in
    order: every folder of ``ROS_PACKAGE_PATH`` (a package folder, with its package.xml, counts
    as its parent), then the share folder of the installed example-robot-data."""
    import os

    dirs: list[str] = []
    for d in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
        if not d:
            continue
        # A package folder (it holds package.xml) resolves as its parent: <parent>/<package>/...
        p = Path(d)
        dirs.append(str(p.parent if (p / "package.xml").exists() else p))
    prefix = Path(pin.__file__).resolve()
    for parent in prefix.parents:
        share = parent / "share"
        if (share / "example-robot-data").is_dir():
            dirs.append(str(share))
            break
    if not dirs:
        raise ProblemError(
            "no package search path: set ROS_PACKAGE_PATH (example-robot-data not found either)"
        )
    return dirs


def _prefixed_urdf(urdf: Path, prefix: str) -> str:
    """URDF text with every link/joint name prefixed ``prefix/`` and mesh paths made absolute."""
    tree = ET.parse(urdf)
    root = tree.getroot()
    for tag in ("link", "joint"):
        for el in root.iter(tag):
            if "name" in el.attrib and el in list(root):
                el.attrib["name"] = f"{prefix}/{el.attrib['name']}"
    for el in root.iter():
        if el.tag in ("parent", "child") and "link" in el.attrib:
            el.attrib["link"] = f"{prefix}/{el.attrib['link']}"
        if el.tag == "mimic" and "joint" in el.attrib:
            el.attrib["joint"] = f"{prefix}/{el.attrib['joint']}"
        if el.tag == "mesh" and "filename" in el.attrib:
            fn = el.attrib["filename"]
            if not fn.startswith("package://") and not Path(fn).is_absolute():
                el.attrib["filename"] = str((urdf.parent / fn).resolve())
    root.attrib["name"] = prefix
    return ET.tostring(root, encoding="unicode")


def _pose_from_xml(el: ET.Element) -> pin.SE3:
    """HPP SRDF pose: ``<position xyz= wxyz=/>`` or text ``x y z qw qx qy qz``."""
    if "xyz" in el.attrib or "wxyz" in el.attrib or "rpy" in el.attrib:
        xyz = [float(v) for v in el.attrib.get("xyz", "0 0 0").split()]
        if "wxyz" in el.attrib:
            w, x, y, z = (float(v) for v in el.attrib["wxyz"].split())
            R = pin.Quaternion(w, x, y, z).normalized().toRotationMatrix()
        elif "rpy" in el.attrib:
            R = pin.rpy.rpyToMatrix(*(float(v) for v in el.attrib["rpy"].split()))
        else:
            R = np.eye(3)
        return pin.SE3(R, np.array(xyz))
    vals = [float(v) for v in (el.text or "").split()]
    if len(vals) != 7:
        raise ProblemError(f"<position> needs 7 numbers 'x y z qw qx qy qz', got {vals}")
    w, x, y, z = vals[3:]
    return pin.SE3(pin.Quaternion(w, x, y, z).normalized().toRotationMatrix(), np.array(vals[:3]))


@dataclasses.dataclass
class _SrdfInfo:
    grippers: list[tuple[str, str, pin.SE3, float]]  # name, link, pose in link, clearance
    handles: list[tuple[str, str, pin.SE3, float, tuple[bool, ...], tuple[float, float, float]]]
    contacts: list[tuple[str, str, np.ndarray]]  # name, link, points (k x 3) in link
    disabled: list[tuple[str, str]]


_TRUE = {"1", "true"}
_FALSE = {"0", "false"}


def _mask(text: str | None, what: str) -> tuple[bool, ...]:
    """An HPP ``<mask>``: six entries, each 1 / 0 or true / false (any case)."""
    words = (text or "").split()
    out = []
    for w in words:
        if w.lower() in _TRUE:
            out.append(True)
        elif w.lower() in _FALSE:
            out.append(False)
        else:
            raise ProblemError(f"{what}: mask entry {w!r} is not 1 / 0 or true / false")
    if len(out) != 6:
        raise ProblemError(f"{what}: a mask has 6 entries (x y z rx ry rz), got {len(out)}")
    return tuple(out)


def _parse_srdf(path: Path) -> _SrdfInfo:
    """Grippers, handles, contacts and disabled pairs of an HPP SRDF; a malformed tag is one
    :class:`ProblemError` naming the file, the tag and what is wrong."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise ProblemError(f"{path}: XML syntax error: {e}") from None
    try:
        return _srdf_info(root, path)
    except (AttributeError, KeyError, ValueError) as e:
        raise ProblemError(f"{path}: malformed SRDF ({type(e).__name__}: {e})") from None


def _approach(values: Any, what: str) -> tuple[float, float, float]:
    """A handle's approach axis: three numbers."""
    xyz = tuple(float(v) for v in values)
    if len(xyz) != 3:
        raise ProblemError(f"{what}: the approach axis needs 3 numbers (x y z), got {len(xyz)}")
    return xyz[0], xyz[1], xyz[2]


def _child(el: ET.Element, tag: str, path: Path) -> ET.Element:
    """The ``<tag>`` child of an SRDF element; its absence is a :class:`ProblemError`."""
    child = el.find(tag)
    if child is None:
        raise ProblemError(f"{path}: <{el.tag} name={el.attrib.get('name')!r}> has no <{tag}>")
    return child


def _srdf_info(root: ET.Element, path: Path) -> _SrdfInfo:
    info = _SrdfInfo([], [], [], [])
    for g in root.iter("gripper"):
        link = _child(g, "link", path).attrib["name"]
        info.grippers.append(
            (
                g.attrib["name"],
                link,
                _pose_from_xml(_child(g, "position", path)),
                float(g.attrib.get("clearance", 0.0)),
            )
        )
    for h in root.iter("handle"):
        link = _child(h, "link", path).attrib["name"]
        mask = tuple(True for _ in range(6))
        m = h.find("mask")
        if m is not None:
            mask = _mask(m.text, f"{path}: handle {h.attrib.get('name')}")
        approach = (1.0, 0.0, 0.0)
        a = h.find("approaching_direction")
        if a is not None:
            approach = _approach(a.attrib["xyz"].split(), f"{path}: handle {h.attrib.get('name')}")
        info.handles.append(
            (
                h.attrib["name"],
                link,
                _pose_from_xml(_child(h, "position", path)),
                float(h.attrib.get("clearance", 0.0)),
                mask,
                approach,
            )
        )
    for c in root.iter("contact"):
        link = _child(c, "link", path).attrib["name"]
        point_text = _child(c, "point", path).text or ""
        pts = np.array([float(v) for v in point_text.split()]).reshape(-1, 3)
        shape = c.find("shape")
        if shape is not None:
            idx = [int(v) for v in (shape.text or "").split()]
            if not idx:
                raise ProblemError(f"{path}: contact {c.attrib.get('name')!r} has an empty <shape>")
            pts = pts[idx[1 : 1 + idx[0]]]
        info.contacts.append((c.attrib["name"], link, pts))
    for d in root.iter("disable_collisions"):
        info.disabled.append((d.attrib["link1"], d.attrib["link2"]))
    return info


def polygon_frame(points: np.ndarray) -> tuple[pin.SE3, np.ndarray]:
    """Frame S of a planar polygon (origin: centroid, z: outward normal by the right-hand rule,
    x: towards the first vertex) and its vertices (k x 2) in S's xy plane."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise ProblemError(f"a contact polygon needs >= 3 points (k x 3), got shape {pts.shape}")
    c = pts.mean(axis=0)
    n = np.zeros(3)
    for i in range(len(pts)):  # Newell's normal: robust for any planar polygon
        a, b = pts[i] - c, pts[(i + 1) % len(pts)] - c
        n += np.cross(a, b)
    if np.linalg.norm(n) < 1e-12:
        raise ProblemError("degenerate contact polygon (zero area)")
    z = n / np.linalg.norm(n)
    x = pts[0] - c
    x -= z * x.dot(z)
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    M = pin.SE3(R, c)
    local = (pts - c) @ R
    if np.max(np.abs(local[:, 2])) > 1e-6:
        raise ProblemError("contact polygon points are not coplanar")
    return M, local[:, :2].copy()


def _from_models(entry: dict[str, Any]) -> dict[str, Any]:
    """Resolve ``robot: <name>`` / ``object: <name>`` through :mod:`marionette.robots`
    (models/<robot>/, models/objects/<object>.urdf + .yaml); explicit keys win."""
    if "robot" not in entry and "object" not in entry:
        return entry
    from marionette import robots
    from marionette.models.semantics import load_semantics

    out = dict(entry)
    try:
        if "robot" in entry:
            d = robots.robot(entry["robot"])
            out.setdefault("urdf", str(d.urdf))
            out.setdefault("srdf", str(d.srdf))
            out.setdefault("semantics", robots.semantics(entry["robot"]))
        else:
            out.setdefault("urdf", str(robots.object_urdf(entry["object"])))
            yaml_path = robots.object_urdf(entry["object"]).with_suffix(".yaml")
            if yaml_path.exists():
                out.setdefault("semantics", load_semantics(yaml_path))
    except KeyError as e:
        raise ProblemError(f"unknown model: {e}") from e
    return out


def _robot_root(entry: dict[str, Any]) -> str:
    if "robot" not in entry:
        return "fixed"
    from marionette import robots

    try:
        base = robots.robot(entry["robot"]).base
    except KeyError as e:
        raise ProblemError(f"unknown model: {e}") from e
    if base not in ("free_flyer", "fixed"):
        raise ProblemError(f"robot {entry['robot']}: base '{base}' is not supported by the planner")
    return "freeflyer" if base == "free_flyer" else "fixed"


def _add_semantics(sem: Any, info: _SrdfInfo, owner: str) -> None:
    """Grippers/handles/contacts of a :class:`marionette.models.semantics.Semantics` (names there
    are already ``<owner>/<name>``). The robot's description is the one the controllers use: an
    SRDF entry of the same name (an HPP SRDF shipped with the robot declares its grippers too,
    with another clearance) gives way to it."""

    def local(n: str) -> str:
        return n.split("/", 1)[1] if "/" in n else n

    described = {local(e.name) for e in (*sem.grippers, *sem.handles, *sem.contacts)}
    info.grippers[:] = [g for g in info.grippers if g[0] not in described]
    info.handles[:] = [h for h in info.handles if h[0] not in described]
    info.contacts[:] = [c for c in info.contacts if c[0] not in described]
    for g in sem.grippers:
        info.grippers.append((local(g.name), g.link, g.pose.se3(), float(g.clearance)))
    for h in sem.handles:
        info.handles.append(
            (
                local(h.name),
                h.link,
                h.pose.se3(),
                float(h.clearance),
                tuple(bool(v) for v in h.mask),
                _approach(h.approach, f"{owner}/{local(h.name)}"),
            )
        )
    for c in sem.contacts:
        info.contacts.append((local(c.name), c.link, np.asarray(c.points, dtype=float)))


def _inline(entry: dict[str, Any], info: _SrdfInfo, owner: str) -> None:
    """Grippers / handles / contacts declared in the problem file, same fields as the SRDF tags.

    ``grippers: [{name, link, pose: [x y z qx qy qz qw], clearance}]``,
    ``handles: [{name, link, pose, clearance, mask: [6 x 0/1], approach: [x y z]}]``,
    ``contacts: [{name, link, points: [[x y z], ...]}]`` (counter-clockwise seen from outside).
    """
    try:
        for g in entry.get("grippers", []) or []:
            info.grippers.append(
                (
                    g["name"],
                    g["link"],
                    _pose7(g.get("pose", [0, 0, 0, 0, 0, 0, 1]), f"{owner}/{g['name']}.pose"),
                    float(g.get("clearance", 0.0)),
                )
            )
        for h in entry.get("handles", []) or []:
            info.handles.append(
                (
                    h["name"],
                    h["link"],
                    _pose7(h.get("pose", [0, 0, 0, 0, 0, 0, 1]), f"{owner}/{h['name']}.pose"),
                    float(h.get("clearance", 0.0)),
                    tuple(bool(v) for v in h.get("mask", [1] * 6)),
                    _approach(h.get("approach", [1, 0, 0]), f"{owner}/{h['name']}.approach"),
                )
            )
        for c in entry.get("contacts", []) or []:
            info.contacts.append((c["name"], c["link"], np.asarray(c["points"], dtype=float)))
    except KeyError as e:
        raise ProblemError(f"{owner}: gripper/handle/contact entry misses {e}") from e


def _refuse_duplicates(info: _SrdfInfo, owner: str) -> None:
    """Two grippers, handles or contacts of one model with the same name (the SRDF and the
    problem file both declaring it) would be two frames of one name: refused."""
    for kind, entries in (
        ("gripper", info.grippers),
        ("handle", info.handles),
        ("contact", info.contacts),
    ):
        names = [e[0] for e in entries]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ProblemError(
                f"{kind} {owner}/{twice[0]} is declared twice (SRDF and problem file?): "
                "keep one declaration"
            )


def _load_yaml(path: Path) -> dict[str, Any]:
    try:
        data = read_yaml(path)
    except DataFileError as e:
        raise ProblemError(str(e)) from None
    if not isinstance(data, dict):
        raise ProblemError(f"{path}: a problem file is a YAML mapping")
    return data


def load_problem(path: str | Path) -> ManipulationProblem:
    """Build a :class:`ManipulationProblem` from a YAML problem file (validated against
    ``marionette/schemas/problem.schema.json`` first: unknown keys and wrong types are refused)."""
    path = Path(path).resolve()
    desc = _load_yaml(path)
    try:
        return build_problem(desc, base=path.parent, source=path)
    except ProblemError as e:
        raise ProblemError(f"{path}: {e}") from None


def _pose7(v: Any, what: str) -> pin.SE3:
    if isinstance(v, dict):
        v = list(v.get("xyz", [0, 0, 0])) + list(v.get("xyzw", [0, 0, 0, 1]))
    a = np.asarray(v, dtype=float)
    if a.shape != (7,):
        raise ProblemError(f"{what}: a pose is [x, y, z, qx, qy, qz, qw], got {v}")
    return pin.XYZQUATToSE3(a)


def build_problem(
    desc: dict[str, Any], base: Path, source: Path | None = None
) -> ManipulationProblem:
    """Build the problem from an already parsed description (see :func:`load_problem`)."""
    from marionette.planning.problem_schema import validate_problem

    bad = validate_problem(desc)
    if bad is not None:
        raise ProblemError(bad)
    model = pin.Model()
    geom = pin.GeometryModel()
    disabled: set[frozenset[str]] = set()
    srdf_infos: list[tuple[str, _SrdfInfo]] = []
    sources: list[ModelSource] = []
    robot_names = []
    robot_joint_ids: list[int] = []
    joint_bounds: dict[str, tuple[float, float]] = {}

    def append(name: str, entry: dict[str, Any], root: str) -> None:
        nonlocal model, geom
        entry = _from_models(entry)
        if "urdf" not in entry:
            raise ProblemError(
                f"{name}: give 'urdf' (and 'srdf'), 'robot: <name>' or 'object: <name>'"
            )
        urdf = _resolve(entry["urdf"], base)
        try:
            xml = _prefixed_urdf(urdf, name)
        except ET.ParseError as e:
            raise ProblemError(f"{urdf}: XML syntax error: {e}") from None
        try:
            if root == "freeflyer":
                sub = pin.buildModelFromXML(xml, pin.JointModelFreeFlyer(), f"{name}/root_joint")
            elif root == "fixed":
                sub = pin.buildModelFromXML(xml)
            else:
                raise ProblemError(f"{name}: root_joint must be 'fixed' or 'freeflyer', got {root}")
        except (ValueError, RuntimeError) as e:
            raise ProblemError(f"{urdf}: not a URDF Pinocchio can read: {e}") from None
        try:
            sub_geom = pin.buildGeomFromUrdfString(
                sub, xml, pin.GeometryType.COLLISION, package_dirs=_package_dirs()
            )
        except (ValueError, RuntimeError) as e:
            raise ProblemError(f"{name}: collision meshes of {urdf}: {e}") from None
        pose = _pose7(entry.get("pose", [0, 0, 0, 0, 0, 0, 1]), f"{name}.pose")
        if model.njoints == 1 and model.nframes <= 1:
            # First model: keep it as is (frame 0 = universe), placed at `pose`.
            if not pose.isIdentity():
                if root == "freeflyer":
                    raise ProblemError(
                        f"{name}: a free-flyer root takes its pose from q, not 'pose'"
                    )
                model_, geom_ = pin.appendModel(
                    pin.Model(), sub, pin.GeometryModel(), sub_geom, 0, pose
                )
                model, geom = model_, geom_
            else:
                model, geom = sub, sub_geom
        else:
            model, geom = pin.appendModel(model, sub, geom, sub_geom, 0, pose)
        info = (
            _parse_srdf(_resolve(entry["srdf"], base))
            if "srdf" in entry
            else _SrdfInfo([], [], [], [])
        )
        if "semantics" in entry:
            _add_semantics(entry["semantics"], info, name)
        _inline(entry, info, name)
        _refuse_duplicates(info, name)
        for pair in entry.get("disable_collisions", []) or []:
            if len(pair) != 2:
                raise ProblemError(f"{name}.disable_collisions: pairs of link names, got {pair}")
            info.disabled.append((str(pair[0]), str(pair[1])))
        srdf_infos.append((name, info))
        sources.append(
            ModelSource(
                name,
                urdf,
                root,
                pose,
                tuple(info.grippers),
                tuple(info.handles),
                tuple(info.contacts),
                tuple(info.disabled),
            )
        )

    for r in desc["robots"]:
        name = r.get("name", r.get("robot"))
        before = model.njoints
        append(name, r, r["root_joint"] if "root_joint" in r else _robot_root(r))
        robot_names.append(name)
        robot_joint_ids.extend(range(before, model.njoints))
        for jn, b in (r.get("joint_bounds") or {}).items():
            joint_bounds[f"{name}/{jn}"] = (float(b[0]), float(b[1]))
    object_entries = desc.get("objects", []) or []
    for o in object_entries:
        o.setdefault("name", o.get("object"))
        append(o["name"], o, "freeflyer")
    for e in desc.get("environment", []) or []:
        e.setdefault("name", e.get("object"))
        append(e["name"], e, "fixed")

    # Grippers, handles, contacts become frames / surfaces of the combined model.
    grippers: dict[str, Gripper] = {}
    handles_raw: list[
        tuple[str, str, str, pin.SE3, float, tuple[bool, ...], tuple[float, float, float]]
    ] = []
    contacts: dict[str, ContactSurface] = {}
    for owner, info in srdf_infos:
        for a, b in info.disabled:
            disabled.add(frozenset((f"{owner}/{a}", f"{owner}/{b}")))
        for gname, link, M_LG, clearance in info.grippers:
            lf = model.getFrameId(f"{owner}/{link}")
            if lf >= model.nframes:
                raise ProblemError(f"gripper {owner}/{gname}: no link {owner}/{link}")
            frame = model.frames[lf]
            fid = model.addFrame(
                pin.Frame(
                    f"{owner}/{gname}",
                    frame.parentJoint,
                    lf,
                    frame.placement * M_LG,
                    pin.FrameType.OP_FRAME,
                )
            )
            grippers[f"{owner}/{gname}"] = Gripper(
                f"{owner}/{gname}", fid, frame.parentJoint, clearance
            )
        for hname, link, M_LH, clearance, mask, approach in info.handles:
            handles_raw.append((owner, hname, link, M_LH, clearance, mask, approach))
        for cname, link, pts in info.contacts:
            lf = model.getFrameId(f"{owner}/{link}")
            if lf >= model.nframes:
                raise ProblemError(f"contact {owner}/{cname}: no link {owner}/{link}")
            frame = model.frames[lf]
            M_LS, poly = polygon_frame(pts)
            is_object = any(o["name"] == owner for o in object_entries)
            contacts[f"{owner}/{cname}"] = ContactSurface(
                f"{owner}/{cname}",
                owner if is_object else None,
                frame.parentJoint,
                frame.placement * M_LS,
                poly,
            )
    handles: dict[str, Handle] = {}
    for owner, hname, link, M_LH, clearance, mask, approach in handles_raw:
        lf = model.getFrameId(f"{owner}/{link}")
        if lf >= model.nframes:
            raise ProblemError(f"handle {owner}/{hname}: no link {owner}/{link}")
        frame = model.frames[lf]
        fid = model.addFrame(
            pin.Frame(
                f"{owner}/{hname}",
                frame.parentJoint,
                lf,
                frame.placement * M_LH,
                pin.FrameType.OP_FRAME,
            )
        )
        handles[f"{owner}/{hname}"] = Handle(
            f"{owner}/{hname}", owner, fid, frame.parentJoint, clearance, mask, approach
        )

    objects: dict[str, ObjectInfo] = {}
    for o in object_entries:
        jid = model.getJointId(f"{o['name']}/root_joint")
        objects[o["name"]] = ObjectInfo(
            o["name"],
            jid,
            model.idx_qs[jid],
            model.idx_vs[jid],
            tuple(h for h in handles if handles[h].object == o["name"]),
            tuple(c for c in contacts if contacts[c].owner == o["name"]),
        )

    # Bounds: URDF limits overridden by the problem's; object translations from 'bounds'.
    lower = model.lowerPositionLimit.copy()
    upper = model.upperPositionLimit.copy()
    for jn, (lo, hi) in joint_bounds.items():
        if not model.existJointName(jn):
            raise ProblemError(f"joint_bounds: no joint {jn}")
        jid = model.getJointId(jn)
        lower[model.idx_qs[jid]], upper[model.idx_qs[jid]] = lo, hi
    for r in desc["robots"]:
        if "root_bounds" in r:
            name = r.get("name", r.get("robot"))
            b = np.asarray(r["root_bounds"], dtype=float)
            jn = f"{name}/root_joint"
            if not model.existJointName(jn) or model.joints[model.getJointId(jn)].nq != 7:
                raise ProblemError(f"{name}.root_bounds: the robot has no free-flyer root")
            if b.shape != (6,) or np.any(b[1::2] < b[0::2]):
                raise ProblemError(
                    f"{name}.root_bounds: [xmin, xmax, ymin, ymax, zmin, zmax], got {b}"
                )
            i = model.idx_qs[model.getJointId(jn)]
            lower[i : i + 3], upper[i : i + 3] = b[0::2], b[1::2]
            lower[i + 3 : i + 7], upper[i + 3 : i + 7] = -1.0001, 1.0001
    for o in object_entries:
        b = np.asarray(o.get("bounds", [-1, 1, -1, 1, -1, 1]), dtype=float)
        if b.shape != (6,) or np.any(b[1::2] < b[0::2]):
            raise ProblemError(f"{o['name']}.bounds: [xmin, xmax, ymin, ymax, zmin, zmax], got {b}")
        i = objects[o["name"]].idx_q
        lower[i : i + 3], upper[i : i + 3] = b[0::2], b[1::2]
        lower[i + 3 : i + 7], upper[i + 3 : i + 7] = -1.0001, 1.0001
    model.lowerPositionLimit = lower
    model.upperPositionLimit = upper
    unbounded = [
        lab
        for lab, lo, hi in zip(_layout(model), lower, upper)
        if not (np.isfinite(lo) and np.isfinite(hi))
    ]
    if unbounded:
        raise ProblemError(
            f"configuration entries without finite bounds (sampling needs them; "
            f"give root_bounds / bounds / joint_bounds): {unbounded}"
        )

    _add_collision_pairs(model, geom, disabled)

    settings = dict(desc.get("graph", {}) or {})
    settings["planner"] = dict(desc.get("planner", {}) or {})
    settings["guide"] = list(desc.get("guide", []) or [])
    env_contacts = tuple(
        settings.get("environment_contacts", [c for c in contacts if contacts[c].owner is None])
    )
    for c in env_contacts:
        if c not in contacts:
            raise ProblemError(f"environment contact '{c}' is not declared")

    problem = ManipulationProblem(
        name=desc["name"],
        model=model,
        geom_model=geom,
        grippers=grippers,
        handles=handles,
        contacts=contacts,
        objects=objects,
        environment_contacts=env_contacts,
        lower=lower,
        upper=upper,
        q_init=np.zeros(model.nq),
        q_goal=None,
        robot_names=tuple(robot_names),
        settings=settings,
        source=source,
        robot_joint_ids=tuple(robot_joint_ids),
        freeflyer_idx_q=tuple(
            model.idx_qs[j] for j in range(1, model.njoints) if model.joints[j].nq == 7
        ),
        models=tuple(sources),
    )
    problem.fixed_rotation_idx_q = tuple(
        model.idx_qs[model.getJointId(f"{r.get('name', r.get('robot'))}/root_joint")]
        for r in desc["robots"]
        if r.get("sample_root_rotation", True) is False
    )
    robot_models = {r.get("name", r.get("robot")): r.get("robot") for r in desc["robots"]}
    problem.q_init = (
        _configuration(problem, desc["init"], "init", robot_models)
        if desc.get("init") is not None
        else None
    )
    if desc.get("goal") is not None:
        problem.q_goal = _configuration(problem, desc["goal"], "goal", robot_models)
    return problem


def _configuration(
    problem: ManipulationProblem,
    value: Any,
    what: str,
    robot_models: dict[str, str | None] | None = None,
) -> np.ndarray:
    """A configuration: a flat list (nq), or a mapping {robot: 'reference' | [q], object: pose}
    in the order of the model (robots, then objects)."""
    if isinstance(value, dict):
        parts = []
        for name in list(problem.robot_names) + list(problem.objects):
            if name not in value:
                raise ProblemError(f"{what}: no entry for '{name}'")
            v = value[name]
            if name in problem.objects:
                parts.append(pin.SE3ToXYZQUAT(_pose7(v, f"{what}.{name}")))
            elif isinstance(v, str):
                model_name = (robot_models or {}).get(name)
                if model_name is None:
                    raise ProblemError(
                        f"{what}.{name}: '{v}' needs a robot given by 'robot: <name>'"
                    )
                parts.append(_reference_of(problem, name, model_name))
            else:
                parts.append(np.asarray(v, dtype=float))
        unknown = set(value) - set(problem.robot_names) - set(problem.objects)
        if unknown:
            raise ProblemError(f"{what}: unknown names {sorted(unknown)}")
        value = np.concatenate(parts)
    if value is None:
        raise ProblemError(f"problem misses '{what}' (a configuration of size nq={problem.nq})")
    q = np.asarray(value, dtype=float)
    if q.shape != (problem.nq,):
        raise ProblemError(
            f"{what}: expected {problem.nq} values "
            f"({', '.join(problem.configuration_layout())}), got {q.shape}"
        )
    for o in problem.objects.values():
        quat = q[o.idx_q + 3 : o.idx_q + 7]
        if abs(np.linalg.norm(quat) - 1.0) > 1e-6:
            raise ProblemError(f"{what}: quaternion of {o.name} is not unit: {quat}")
    return q


def _reference_of(problem: ManipulationProblem, name: str, model_name: str) -> np.ndarray:
    """Robot ``name``'s part of a configuration at its model's reference posture, joint by joint:
    the problem may root the robot differently (``root_joint: fixed`` for a planar base held still),
    so the reference's base coordinates are dropped then."""
    from marionette import robots

    full, _ = robots.load_pinocchio(model_name, with_collision=False)
    q_ref = np.asarray(robots.reference_configuration(model_name), dtype=float)
    prefix = f"{name}/"
    parts = []
    for jid in range(1, problem.model.njoints):
        jname = problem.model.names[jid]
        if not jname.startswith(prefix):
            continue
        local = jname[len(prefix) :]
        if not full.existJointName(local):
            raise ProblemError(f"{name}: joint {local} is not in robot model {model_name}")
        j = full.joints[full.getJointId(local)]
        parts.append(q_ref[j.idx_q : j.idx_q + j.nq])
    return np.concatenate(parts) if parts else np.zeros(0)


def _add_collision_pairs(
    model: pin.Model, geom: pin.GeometryModel, disabled: set[frozenset[str]]
) -> None:
    """All pairs of geometries on different joints, except SRDF-disabled link pairs and pairs of
    two fixed bodies (both on the universe)."""
    objs = geom.geometryObjects
    links = [model.frames[o.parentFrame].name for o in objs]
    for i in range(len(objs)):
        for j in range(i + 1, len(objs)):
            ji, jj = objs[i].parentJoint, objs[j].parentJoint
            if ji == jj:
                continue
            if frozenset((links[i], links[j])) in disabled:
                continue
            geom.addCollisionPair(pin.CollisionPair(i, j))


def random_configuration(
    problem: ManipulationProblem, rng: np.random.Generator, out: np.ndarray | None = None
) -> np.ndarray:
    """Uniform sample in the bounds; free-flyer rotations uniform on SO(3) (Shoemake)."""
    q = out if out is not None else np.empty(problem.nq)
    q[:] = problem.lower + rng.random(problem.nq) * (problem.upper - problem.lower)
    for i in problem.freeflyer_idx_q:
        if i in problem.fixed_rotation_idx_q and problem.q_init is not None:
            q[i + 3 : i + 7] = problem.q_init[i + 3 : i + 7]
            continue
        u1, u2, u3 = rng.random(3)
        a, b = math.sqrt(1 - u1), math.sqrt(u1)
        q[i + 3 : i + 7] = (
            a * math.sin(2 * math.pi * u2),
            a * math.cos(2 * math.pi * u2),
            b * math.sin(2 * math.pi * u3),
            b * math.cos(2 * math.pi * u3),
        )
    return q


def sample_configuration(
    problem: ManipulationProblem, rng: np.random.Generator, out: np.ndarray | None = None
) -> np.ndarray:
    """The planner's sampler: uniform (:func:`random_configuration`) unless the problem's
    ``planner.sampler`` asks for ``{around: init, sigma: s, uniform_fraction: f}``: then with
    probability 1 - f a Gaussian perturbation (std ``sigma`` on every velocity coordinate) of
    the initial configuration, clipped to the bounds -- humanoids rarely project random
    whole-body postures onto balanced, collision-free ones; the uniform share keeps the
    sampling dense everywhere (probabilistic completeness)."""
    cfg = problem.settings.get("planner", {}).get("sampler")
    if not cfg or problem.q_init is None or rng.random() < float(cfg.get("uniform_fraction", 0.2)):
        return random_configuration(problem, rng, out)
    sigma = float(cfg.get("sigma", 0.5))
    q = pin.integrate(problem.model, problem.q_init, rng.normal(scale=sigma, size=problem.nv))
    q = np.clip(q, problem.lower, problem.upper)
    for i in problem.freeflyer_idx_q:
        q[i + 3 : i + 7] /= np.linalg.norm(q[i + 3 : i + 7])
    if out is not None:
        out[:] = q
        return out
    return q
