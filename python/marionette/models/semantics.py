"""What SRDF adds to a URDF, declared in YAML the way HPP declares it: grippers, handles,
contact surfaces and AprilTags.

Conventions (Nicolin 2022, §3.2.1; HPP ``hpp-manipulation``):

* A **gripper** is a frame on the robot, a **handle** a frame on an object. A **grasp** puts the
  gripper frame onto the handle frame (the components selected by the handle's ``mask``).
* Both frames have their **x axis along the approach**: it points from the gripper into the
  object. The **pre-grasp** puts the gripper back along that axis by
  ``gripper.clearance + handle.clearance`` (:func:`pregrasp_distance`). A handle's clearance
  alone already takes the gripper frame out of the object (models/README.md).
* A **contact surface** is a convex polygon in its link frame, vertices counter-clockwise seen
  from outside the body, so the right-hand normal points out of the body.
* A **tag** frame follows ViSP's default ``vpDetectorAprilTag`` pose (``setZAlignedWithCameraAxis``
  false): origin at the tag centre, z out of the printed face towards a viewer, x to the right
  and y up in the upright tag image. ``size`` is the edge of the black square (the detector's
  ``tagSize``); the printed white border adds one cell on each side.

Poses are ``{xyz: [x, y, z], xyzw: [qx, qy, qz, qw]}``: metres, unit quaternion in
Pinocchio's (Eigen's) coefficient order. MuJoCo orders quaternions w, x, y, z.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

import numpy as np
import yaml

from marionette.schemas import DataFileError, read_yaml


class SemanticsError(ValueError):
    """A YAML declaration is malformed; the message names the file and the entry."""


# Parameters of a gripper_admittance task
# (cpp/include/marionette/controller/gripper_admittance_spec.h;
# marionette.control.spec checks task specs against it).
GRIPPER_ADMITTANCE_PARAMETERS = (
    "force_target",
    "force_threshold",
    "release_force",
    "admittance_gain",
    "lever_arm",
    "torque_per_effort",
    "cutoff_frequency",
    "speed",
    "acceleration",
    "release_rate",
    "closing_direction",
    "release",
    "release_after",
)
# Those a gripper may set in its semantics (the factory derives the others from the step and the
# gripper's open / closed positions).
ADMITTANCE_PARAMETERS = frozenset(GRIPPER_ADMITTANCE_PARAMETERS) - {
    "closing_direction",
    "release",
    "release_after",
}


@dataclass(frozen=True)
class Placement:
    """A rigid placement X_PF of a frame F in its parent frame P."""

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        if len(self.xyz) != 3 or len(self.xyzw) != 4:
            raise SemanticsError(f"placement needs 3 + 4 numbers, got {self.xyz} {self.xyzw}")
        if not all(np.isfinite(self.xyz)) or not all(np.isfinite(self.xyzw)):
            raise SemanticsError(f"placement has non-finite numbers: {self.xyz} {self.xyzw}")
        norm = float(np.linalg.norm(self.xyzw))
        if abs(norm - 1.0) > 1e-6:
            raise SemanticsError(f"quaternion xyzw {list(self.xyzw)} has norm {norm}, not 1")

    @staticmethod
    def from_matrix(X: np.ndarray) -> Placement:
        """From a 4 x 4 homogeneous matrix (rotation must be orthonormal)."""
        import pinocchio as pin

        X = np.asarray(X, dtype=float)
        M = pin.SE3(X[:3, :3], X[:3, 3])
        v = pin.SE3ToXYZQUAT(M)
        q = v[3:] / np.linalg.norm(v[3:])
        if q[3] < 0:  # one representative of q ~ -q, so files are deterministic
            q = -q
        x, y, z = (float(a) for a in v[:3])
        qx, qy, qz, qw = (float(a) for a in q)
        return Placement((x, y, z), (qx, qy, qz, qw))

    def matrix(self) -> np.ndarray:
        """The 4 x 4 homogeneous matrix X_PF."""
        x, y, z, w = np.asarray(self.xyzw) / np.linalg.norm(self.xyzw)
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        X = np.eye(4)
        X[:3, :3] = R
        X[:3, 3] = self.xyz
        return X

    def se3(self):
        """The placement as a ``pinocchio.SE3``."""
        import pinocchio as pin

        q = np.asarray(self.xyzw) / np.linalg.norm(self.xyzw)
        return pin.XYZQUATToSE3(np.array([*self.xyz, *q]))

    def to_dict(self) -> dict[str, list[float]]:
        return {"xyz": [_clean(a) for a in self.xyz], "xyzw": [_clean(a) for a in self.xyzw]}


@dataclass(frozen=True)
class Gripper:
    """A robot (or tool) frame that grasps handles.

    ``name`` is ``<robot>/<gripper>``; ``pose`` places the gripper frame in ``link``.
    ``joint`` is the finger joint, or None for a tool tip; ``open_position`` and
    ``closed_position`` are its commands [rad or m].
    """

    name: str
    link: str
    pose: Placement
    clearance: float
    joint: str | None = None
    open_position: float | None = None
    closed_position: float | None = None
    # Parameters of its gripper_admittance task that differ from the controller's defaults
    # (ADMITTANCE_PARAMETERS: a slide gripper's force transmission, gain and ramp speed).
    admittance: dict[str, float] = field(default_factory=dict, hash=False)


@dataclass(frozen=True)
class Handle:
    """An object frame that a gripper can grasp; ``name`` is ``<object>/<handle>``.

    ``approach`` is the approach axis in the handle frame (HPP: x). ``mask`` selects which of
    the 6 relative-pose components (3 translations, 3 rotations) the grasp constrains.
    """

    name: str
    link: str
    pose: Placement
    clearance: float
    approach: tuple[float, float, float] = (1.0, 0.0, 0.0)
    mask: tuple[int, int, int, int, int, int] = (1, 1, 1, 1, 1, 1)


@dataclass(frozen=True)
class ContactSurface:
    """A convex polygon of a body that may rest on (or hold) another body's surface."""

    name: str
    link: str
    points: np.ndarray  # (n, 3) in the link frame, counter-clockwise seen from outside

    def normal(self) -> np.ndarray:
        """Unit outward normal (3,) of the polygon, in the link frame."""
        p = self.points
        n = np.cross(p[1] - p[0], p[2] - p[0])
        return n / np.linalg.norm(n)


@dataclass(frozen=True)
class Tag:
    """An AprilTag printed on a body: ``size`` is the black-square edge [m]."""

    id: int
    family: str
    size: float
    link: str
    pose: Placement


@dataclass
class Semantics:
    """Everything declared for one robot or object (one YAML file)."""

    name: str
    grippers: list[Gripper] = field(default_factory=list)
    handles: list[Handle] = field(default_factory=list)
    contacts: list[ContactSurface] = field(default_factory=list)
    tags: list[Tag] = field(default_factory=list)

    def gripper(self, name: str) -> Gripper:
        return _by_name(self.grippers, name, "gripper", self.name)

    def handle(self, name: str) -> Handle:
        return _by_name(self.handles, name, "handle", self.name)

    def contact(self, name: str) -> ContactSurface:
        return _by_name(self.contacts, name, "contact surface", self.name)

    def tag(self, tag_id: int) -> Tag:
        for t in self.tags:
            if t.id == tag_id:
                return t
        raise KeyError(f"{self.name} has no tag {tag_id}; it has {[t.id for t in self.tags]}")

    def links(self) -> set[str]:
        """Every link named by a declaration (each must exist in the URDF)."""
        items: list[Gripper | Handle | ContactSurface | Tag] = [
            *self.grippers,
            *self.handles,
            *self.contacts,
            *self.tags,
        ]
        return {item.link for item in items}

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name}
        if self.grippers:
            out["grippers"] = [_gripper_dict(g) for g in self.grippers]
        if self.handles:
            out["handles"] = [_handle_dict(h) for h in self.handles]
        if self.contacts:
            out["contacts"] = [
                {
                    "name": c.name,
                    "link": c.link,
                    "points": [[_clean(a) for a in p] for p in c.points],
                }
                for c in self.contacts
            ]
        if self.tags:
            out["tags"] = [
                {
                    "id": t.id,
                    "family": t.family,
                    "size": _clean(t.size),
                    "link": t.link,
                    "pose": t.pose.to_dict(),
                }
                for t in self.tags
            ]
        return out


def pregrasp_distance(gripper: Gripper, handle: Handle) -> float:
    """Distance [m] between pre-grasp and grasp along the approach axis (HPP convention)."""
    return gripper.clearance + handle.clearance


def load_semantics(path: str | Path) -> Semantics:
    """Parse a ``models/**/<name>.yaml`` declaration; raises SemanticsError naming the culprit."""
    try:
        data = read_yaml(path)
    except DataFileError as e:
        raise SemanticsError(str(e)) from None
    return semantics_from_dict(data, str(path))


def semantics_from_dict(data: Any, source: str = "<dict>") -> Semantics:
    """Build :class:`Semantics` from parsed YAML, validating every field."""
    if not isinstance(data, dict) or not isinstance(data.get("name"), str):
        raise SemanticsError(f"{source}: top level must be a mapping with a string 'name'")
    unknown = set(data) - {"name", "grippers", "handles", "contacts", "tags"}
    if unknown:
        raise SemanticsError(f"{source}: unknown top-level keys {sorted(unknown)}")
    s = Semantics(name=data["name"])
    for i, g in enumerate(data.get("grippers") or []):
        where = f"{source}: grippers[{i}]"
        _keys(
            g,
            where,
            {"name", "link", "pose", "clearance"},
            {"joint", "open_position", "closed_position", "admittance"},
        )
        joint = g.get("joint")
        if joint is not None and ("open_position" not in g or "closed_position" not in g):
            raise SemanticsError(
                f"{where}: a gripper joint needs open_position and closed_position"
            )
        admittance = g.get("admittance") or {}
        if admittance and joint is None:
            raise SemanticsError(f"{where}: admittance parameters need a gripper joint")
        if not isinstance(admittance, dict) or set(admittance) - ADMITTANCE_PARAMETERS:
            raise SemanticsError(
                f"{where}: admittance must map parameters among "
                f"{sorted(ADMITTANCE_PARAMETERS)} to numbers, got {admittance!r}"
            )
        s.grippers.append(
            Gripper(
                name=_str(g, "name", where),
                link=_str(g, "link", where),
                pose=_placement(g["pose"], where),
                clearance=_nonneg(g, "clearance", where),
                joint=joint,
                open_position=_opt_float(g, "open_position", where),
                closed_position=_opt_float(g, "closed_position", where),
                admittance={k: _float(admittance, k, f"{where}: admittance") for k in admittance},
            )
        )
    for i, h in enumerate(data.get("handles") or []):
        where = f"{source}: handles[{i}]"
        _keys(h, where, {"name", "link", "pose", "clearance"}, {"approach", "mask"})
        approach = tuple(float(a) for a in h.get("approach", (1.0, 0.0, 0.0)))
        if len(approach) != 3 or abs(np.linalg.norm(approach) - 1.0) > 1e-9:
            raise SemanticsError(f"{where}: approach must be a unit 3-vector, got {approach}")
        mask = tuple(int(a) for a in h.get("mask", (1,) * 6))
        if len(mask) != 6 or any(m not in (0, 1) for m in mask):
            raise SemanticsError(f"{where}: mask must be six 0/1 values, got {mask}")
        s.handles.append(
            Handle(
                name=_str(h, "name", where),
                link=_str(h, "link", where),
                pose=_placement(h["pose"], where),
                clearance=_nonneg(h, "clearance", where),
                approach=approach,
                mask=mask,
            )
        )
    for i, c in enumerate(data.get("contacts") or []):
        where = f"{source}: contacts[{i}]"
        _keys(c, where, {"name", "link", "points"}, set())
        pts = np.asarray(c["points"], dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
            raise SemanticsError(f"{where}: points must be a list of >= 3 [x, y, z]")
        s.contacts.append(ContactSurface(_str(c, "name", where), _str(c, "link", where), pts))
    for i, t in enumerate(data.get("tags") or []):
        where = f"{source}: tags[{i}]"
        _keys(t, where, {"id", "family", "size", "link", "pose"}, set())
        if not isinstance(t["id"], int) or t["id"] < 0:
            raise SemanticsError(f"{where}: id must be a non-negative integer, got {t['id']!r}")
        size = _nonneg(t, "size", where)
        if size == 0.0:
            raise SemanticsError(f"{where}: size must be > 0")
        s.tags.append(
            Tag(
                t["id"],
                _str(t, "family", where),
                size,
                _str(t, "link", where),
                _placement(t["pose"], where),
            )
        )
    for kind, items in (("gripper", s.grippers), ("handle", s.handles), ("contact", s.contacts)):
        names = [item.name for item in items]
        if len(set(names)) != len(names):
            raise SemanticsError(f"{source}: duplicate {kind} names in {names}")
    ids = [t.id for t in s.tags]
    if len(set(ids)) != len(ids):
        raise SemanticsError(f"{source}: duplicate tag ids in {ids}")
    return s


def dump_semantics(s: Semantics) -> str:
    """YAML text of ``s`` (deterministic: keys in declaration order, floats rounded)."""
    return yaml.safe_dump(s.to_dict(), sort_keys=False, default_flow_style=None, width=100)


def _gripper_dict(g: Gripper) -> dict[str, Any]:
    d: dict[str, Any] = {
        "name": g.name,
        "link": g.link,
        "pose": g.pose.to_dict(),
        "clearance": _clean(g.clearance),
    }
    if g.joint is not None:
        if g.open_position is None or g.closed_position is None:
            raise SemanticsError(
                f"gripper {g.name}: joint {g.joint} needs open_position and closed_position"
            )
        d.update(
            joint=g.joint,
            open_position=_clean(g.open_position),
            closed_position=_clean(g.closed_position),
        )
    if g.admittance:
        d["admittance"] = {k: _clean(v) for k, v in g.admittance.items()}
    return d


def _handle_dict(h: Handle) -> dict[str, Any]:
    return {
        "name": h.name,
        "link": h.link,
        "pose": h.pose.to_dict(),
        "clearance": _clean(h.clearance),
        "approach": [_clean(a) for a in h.approach],
        "mask": list(h.mask),
    }


def _clean(x: float) -> float:
    """Round to 12 significant digits so generated files do not depend on float noise."""
    v = float(f"{float(x):.12g}")
    return 0.0 if v == 0.0 else v


class _Named(Protocol):
    @property
    def name(self) -> str: ...


_NamedT = TypeVar("_NamedT", bound=_Named)


def _by_name(items: list[_NamedT], name: str, kind: str, owner: str) -> _NamedT:
    for item in items:
        if item.name == name:
            return item
    raise KeyError(f"{owner} has no {kind} {name!r}; it has {[i.name for i in items]}")


def _keys(d: Any, where: str, required: set[str], optional: set[str]) -> None:
    if not isinstance(d, dict):
        raise SemanticsError(f"{where}: must be a mapping, got {type(d).__name__}")
    missing = required - set(d)
    if missing:
        raise SemanticsError(f"{where}: missing keys {sorted(missing)}")
    unknown = set(d) - required - optional
    if unknown:
        raise SemanticsError(f"{where}: unknown keys {sorted(unknown)}")


def _str(d: dict, key: str, where: str) -> str:
    v = d[key]
    if not isinstance(v, str) or not v:
        raise SemanticsError(f"{where}: {key} must be a non-empty string, got {v!r}")
    return v


def _nonneg(d: dict, key: str, where: str) -> float:
    v = d[key]
    if not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
        raise SemanticsError(f"{where}: {key} must be a finite number >= 0, got {v!r}")
    return float(v)


def _opt_float(d: dict, key: str, where: str) -> float | None:
    return _float(d, key, where) if key in d else None


def _float(d: dict, key: str, where: str) -> float:
    v = d[key]
    if not isinstance(v, (int, float)) or not np.isfinite(v):
        raise SemanticsError(f"{where}: {key} must be a finite number, got {v!r}")
    return float(v)


def _placement(d: Any, where: str) -> Placement:
    _keys(d, f"{where}.pose", {"xyz", "xyzw"}, set())
    try:
        x, y, z = (float(a) for a in d["xyz"])
        qx, qy, qz, qw = (float(a) for a in d["xyzw"])
    except (TypeError, ValueError):
        raise SemanticsError(
            f"{where}.pose: xyz and xyzw must be lists of 3 and 4 numbers, got {d['xyz']!r} "
            f"and {d['xyzw']!r}"
        ) from None
    try:
        return Placement((x, y, z), (qx, qy, qz, qw))
    except SemanticsError as e:
        raise SemanticsError(f"{where}.pose: {e}") from None
