"""The one place that knows the robots and objects: found as data, never named in code.

A **robot** is a folder holding ``robot.yaml`` (format: ``schemas/robot.schema.json``, guide:
docs/robots.md) beside its URDF, SRDF and the MJCF generated from them:

* ``<robot>.urdf`` and ``<robot>.srdf`` — what Pinocchio loads (planning, control);
* ``<robot>.xml`` — the MJCF that MuJoCo loads, with the same joints in the same order;
* ``robot.yaml`` — base kind, reference posture, grippers, contact surfaces, tags, feet,
  cameras, range finders, sensors, simulation servos, calibration and walking parameters.

Robots are found by name in the folders of :func:`robot_search_path` (``models/`` and the
folders of ``MARIONETTE_ROBOT_PATH``), or given as a folder path wherever a name is taken.
``marionette-controller`` reads the same ``robot.yaml`` (cpp/src/controller/robots.cc);
``tests/python/controller/test_robots_agree.py`` checks both languages read the same facts.

Joint order is Pinocchio's, and MuJoCo's is the same except for the base, which Pinocchio
models as one joint named ``root_joint`` and MuJoCo as:

============  ===========================================  =====================================
base          Pinocchio ``q`` head                         MuJoCo ``qpos`` head
============  ===========================================  =====================================
free_flyer    x y z qx qy qz qw (JointModelFreeFlyer)      freejoint ``root_joint``: x y z qw qx qy
qz
planar        x y cos(yaw) sin(yaw) (JointModelPlanar)     slides ``root_x``, ``root_y``, hinge
``root_yaw``
fixed         —                                            —
============  ===========================================  =====================================

MuJoCo may also have joints the URDF declares ``<mimic>`` but Pinocchio keeps fixed (a parallel
gripper's second finger), each tied to its driver by an ``<equality><joint>`` when the robot's
``simulation.moving_mimics`` is on; they sit in ``qpos`` where their bodies are, have no
actuator and are not in the controller's configuration. :func:`pinocchio_to_mujoco` and
:func:`mujoco_to_pinocchio` convert configurations (:func:`mujoco_nq`: the size of the robot's
qpos block).
"""

from __future__ import annotations

import os
import subprocess
import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cache, lru_cache
from pathlib import Path
from typing import Any, Literal

import numpy as np

from marionette import MODELS_DIR
from marionette.models.semantics import Semantics, load_semantics, semantics_from_dict
from marionette.models.xml_util import attribute, child, numbers
from marionette.schemas import DataFileError, load_validated

BaseKind = Literal["free_flyer", "planar", "fixed"]
ROBOT_FILE = "robot.yaml"
ROBOT_PATH_VARIABLE = "MARIONETTE_ROBOT_PATH"


@dataclass(frozen=True)
class Foot:
    """A sole: ``frame``'s x-y plane, ``size`` = (length along x, width along y) [m]."""

    name: str
    frame: str
    size: tuple[float, float]
    thickness: float = 0.02


@dataclass(frozen=True)
class Camera:
    """An RGB-D camera: MuJoCo camera ``name`` on optical frame ``frame`` (z along the view);
    ``lean_joints``: what the visual servo's gaze may add to the head's joints when the head
    alone cannot bring a servoed object's tags into view (a torso pitch; the first is used)."""

    name: str
    frame: str
    fovy_deg: float = 45.0
    width: int = 640
    height: int = 480
    lean_joints: tuple[str, ...] = ()

    def intrinsics(self):
        """Its :class:`~marionette.perception.camera.CameraIntrinsics` (square pixels)."""
        from marionette.perception.camera import CameraIntrinsics

        return CameraIntrinsics.from_fovy(self.width, self.height, self.fovy_deg)


@dataclass(frozen=True)
class RangeFinder:
    """A laser range finder: MuJoCo ``rangefinder`` sensor ``name``, its beam along the +z axis
    of frame ``frame`` from its origin; ``noise``: the standard deviation of its readings [m]
    (the simulator adds it)."""

    name: str
    frame: str
    noise: float = 0.0


@dataclass(frozen=True)
class Actuator:
    """Position servo of the joints whose name starts with ``joints``:
    tau = kp (ctrl - q) - kv dq."""

    joints: str
    kp: float
    kv: float
    armature: float = 0.0


@dataclass(frozen=True)
class CalibratedArm:
    """An arm whose encoder offsets the head camera calibrates from the tags on ``tagged_link``."""

    side: str
    joints: tuple[str, ...]
    tagged_link: str
    sampling_box: tuple[tuple[float, float], ...]  # [lower, upper] per joint [rad]
    head_postures: tuple[tuple[float, float], ...]  # (pitch, yaw) [rad]
    max_offset_deg: float = 10.0  # [deg] encoder offsets the view planning finds the ring within


@dataclass(frozen=True)
class RobotDescription:
    """Files and conventions of one robot, as its ``robot.yaml`` declares them.

    ``camera_frame`` is the optical frame of the first camera (x right, y down, z along the
    view) and ``camera`` its MuJoCo name, both None for a robot without one; ``sole_frames``
    are the frames whose x-y plane is the sole of each foot (left first).
    """

    name: str
    directory: Path
    urdf: Path
    srdf: Path
    mjcf: Path
    base: BaseKind
    reference: str
    description: str = ""
    source: str = ""
    meshes: str | None = None  # package:// URI or path of the folder <robot>/meshes links to
    feet: tuple[Foot, ...] = ()
    cameras: tuple[Camera, ...] = ()
    range_finders: tuple[RangeFinder, ...] = ()
    force_torque_sensors: tuple[tuple[str, str], ...] = ()  # (name, link)
    imu_link: str | None = None
    actuators: tuple[Actuator, ...] = ()
    hand_links: tuple[str, ...] = ()
    moving_mimics: bool = True
    # gripper -> its jaws' finger links (+y jaw first), whose contact forces the simulator measures
    grip_bodies: dict[str, tuple[str, ...]] = field(default_factory=dict, hash=False)
    jaws: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = field(
        default_factory=dict, hash=False
    )
    calibration_base_frame: str | None = None
    calibration_head_joints: tuple[str, ...] = ()
    calibrated_arms: tuple[CalibratedArm, ...] = ()
    walking: dict[str, Any] = field(default_factory=dict, hash=False)
    data: dict[str, Any] = field(default_factory=dict, hash=False, repr=False)

    @property
    def semantics(self) -> Path:
        """The file declaring the grippers, contact surfaces and tags: ``robot.yaml``."""
        return self.directory / ROBOT_FILE

    @property
    def camera(self) -> str | None:
        return self.cameras[0].name if self.cameras else None

    @property
    def camera_frame(self) -> str | None:
        return self.cameras[0].frame if self.cameras else None

    @property
    def sole_frames(self) -> tuple[str, ...]:
        return tuple(f.frame for f in self.feet)

    def actuator(self, joint: str) -> Actuator:
        """The servo of ``joint``: the entry naming it exactly, else the first entry whose prefix
        matches its name."""
        for a in self.actuators:
            if joint == a.joints:
                return a
        for a in self.actuators:
            if joint.startswith(a.joints):
                return a
        raise DataFileError(
            f"{self.semantics}: simulation/actuators: no entry matches joint {joint!r}; add one "
            f"whose 'joints' prefix does (an entry with joints: '' matches every joint)"
        )


OBJECTS_DIR = MODELS_DIR / "objects"


class UnknownModel(KeyError):
    """No robot or object of that name; the message lists the known ones."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


def robot_search_path() -> list[Path]:
    """Folders searched for robots, in order: ``models/`` then ``$MARIONETTE_ROBOT_PATH``
    (``:``-separated). Each folder is a robot folder itself or holds robot folders."""
    extra = [Path(p) for p in os.environ.get(ROBOT_PATH_VARIABLE, "").split(os.pathsep) if p]
    return [MODELS_DIR, *extra]


def _robot_folders() -> dict[str, Path]:
    """name -> folder of every robot found on the search path (the first one wins)."""
    found: dict[str, Path] = {}
    for root in robot_search_path():
        candidates = (
            [root] if (root / ROBOT_FILE).is_file() else sorted(root.glob(f"*/{ROBOT_FILE}"))
        )
        for c in candidates:
            folder = c if c.is_dir() else c.parent
            found.setdefault(folder.name, folder)
    return found


def robot_names() -> list[str]:
    """Names of the robots found on the search path."""
    return sorted(_robot_folders())


def robot(name: str | Path) -> RobotDescription:
    """The description of robot ``name`` (a name found on the search path, or the path of a robot
    folder or of its robot.yaml). Raises UnknownModel or DataFileError with a one-line reason."""
    folder = _robot_folder(name)
    return _load_robot(folder.resolve())


def controller_robot_argument(name: str | Path) -> str:
    """Robot ``name`` as a C++ process's ``--robot`` takes it: the folder this Python found.

    A compiled marionette-controller searches the ``models/`` of the checkout it was built in: a
    name alone would find another robot.yaml of that name there, or none (a robot added in
    another checkout or worktree sharing a build), and the controller would drive another robot
    than the one planned for. A folder names the same files on both sides."""
    return str(robot(name).directory)


def _robot_folder(name: str | Path) -> Path:
    text = str(name)
    if os.sep in text or text.endswith(ROBOT_FILE) or Path(text).is_dir():
        p = Path(text)
        folder = p.parent if p.name == ROBOT_FILE else p
        if not (folder / ROBOT_FILE).is_file():
            raise UnknownModel(f"{folder}: no {ROBOT_FILE} there (a robot folder holds one)")
        return folder
    folders = _robot_folders()
    if text not in folders:
        import difflib

        close = difflib.get_close_matches(text, list(folders), n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise UnknownModel(
            f"unknown robot {text!r}{hint}; known robots: {', '.join(sorted(folders))} "
            f"(found in {', '.join(str(p) for p in robot_search_path())}; add folders with "
            f"{ROBOT_PATH_VARIABLE})"
        )
    return folders[text]


@cache
def _load_robot(folder: Path) -> RobotDescription:
    path = folder / ROBOT_FILE
    d = load_validated(path, "robot")
    if d["name"] != folder.name:
        raise DataFileError(
            f"{path}: name {d['name']!r} differs from its folder {folder.name!r}; "
            f"rename one so that they agree"
        )
    sim = d.get("simulation") or {}
    grippers = d.get("grippers") or []
    calibration = d.get("calibration") or {}
    return RobotDescription(
        name=d["name"],
        directory=folder,
        urdf=folder / d["urdf"],
        srdf=folder / d["srdf"],
        mjcf=folder / d["mjcf"],
        base=d["base"],
        reference=d["reference_posture"],
        description=d.get("description", ""),
        source=d.get("source", ""),
        meshes=d.get("meshes"),
        feet=tuple(
            Foot(f["name"], f["frame"], tuple(f["size"]), f.get("thickness", 0.02))
            for f in d.get("feet") or []
        ),
        cameras=tuple(
            Camera(**{**c, "lean_joints": tuple(c.get("lean_joints", ()))})
            for c in d.get("cameras") or []
        ),
        range_finders=tuple(RangeFinder(**r) for r in d.get("range_finders") or []),
        force_torque_sensors=tuple(
            (s["name"], s["link"]) for s in d.get("force_torque_sensors") or []
        ),
        imu_link=(d.get("imu") or {}).get("link"),
        actuators=tuple(Actuator(**a) for a in sim.get("actuators") or []),
        hand_links=tuple(sim.get("hand_links") or [g["link"] for g in grippers]),
        moving_mimics=sim.get("moving_mimics", True),
        jaws={
            g["name"]: (tuple(g["jaws"][0]), tuple(g["jaws"][1])) for g in grippers if "jaws" in g
        },
        grip_bodies={
            g["name"]: tuple(b for jaw in g["jaws"] for b in jaw) for g in grippers if "jaws" in g
        },
        calibration_base_frame=calibration.get("base_frame"),
        calibration_head_joints=tuple(calibration.get("head_joints", ())),
        calibrated_arms=tuple(
            CalibratedArm(
                a["side"],
                tuple(a["joints"]),
                a["tagged_link"],
                tuple(tuple(b) for b in a["sampling_box"]),
                tuple(tuple(h) for h in a["head_postures"]),
                float(a.get("max_offset_deg", 10.0)),
            )
            for a in calibration.get("arms", ())
        ),
        walking=dict(d.get("walking") or {}),
        data=d,
    )


@lru_cache(maxsize=1)
def example_robot_data_dir() -> Path:
    """``<cmeel prefix>/share/example-robot-data/robots`` of the installed wheel."""
    prefix = _cmeel_prefix()
    path = prefix / "share" / "example-robot-data" / "robots"
    if not path.is_dir():
        raise FileNotFoundError(f"{path} missing: scripts/setup installs example-robot-data")
    return path


def package_dirs() -> list[str]:
    """Directories against which ``package://<package>/...`` URIs resolve, in order: the folders of
    ``ROS_PACKAGE_PATH`` (as ROS and HPP use it) then the installed example-robot-data's share/."""
    ros = [p for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    return [*ros, str(example_robot_data_dir().parents[1])]


def resolve_package_uri(uri: str) -> Path:
    """The file or folder a ``package://<package>/<path>`` URI (or a plain path) names; raises
    FileNotFoundError listing where it looked."""
    if not uri.startswith("package://"):
        return Path(uri)
    rel = uri.removeprefix("package://")
    tried = []
    for d in package_dirs():
        for candidate in (Path(d) / rel, Path(d).parent / rel):
            if candidate.exists():
                return candidate
            tried.append(str(candidate.parent))
    raise FileNotFoundError(
        f"{uri}: not found under {', '.join(dict.fromkeys(tried))} "
        f"(add the folder holding its package to ROS_PACKAGE_PATH)"
    )


def load_pinocchio(name: str | Path, with_collision: bool = True):
    """Pinocchio model of robot ``name`` and its collision model (None if not asked for).

    The root joint is ``root_joint``, of the robot's base kind: JointModelFreeFlyer
    (``free_flyer``), JointModelPlanar (``planar``) or none (``fixed``: the URDF's root link is the
    world). Collision pairs are all pairs minus the SRDF's ``disable_collisions``.
    ``model.referenceConfigurations`` holds
    :func:`reference_configuration` under the robot's reference name.
    """
    import pinocchio as pin

    desc = robot(name)
    root = {"free_flyer": pin.JointModelFreeFlyer, "planar": pin.JointModelPlanar}.get(desc.base)
    urdf = str(desc.urdf)
    model = pin.buildModelFromUrdf(urdf, root()) if root else pin.buildModelFromUrdf(urdf)
    model.name = desc.name
    model.referenceConfigurations[desc.reference] = configuration_from_srdf(
        model, desc.srdf.read_text(), desc.reference, semantics(name)
    )
    if not with_collision:
        return model, None
    geom = pin.buildGeomFromUrdf(
        model, urdf, pin.GeometryType.COLLISION, package_dirs=package_dirs()
    )
    geom.addAllCollisionPairs()
    pin.removeCollisionPairs(model, geom, str(desc.srdf))
    return model, geom


def reference_configuration(name: str | Path, model=None) -> np.ndarray:
    """The robot's reference posture (its SRDF ``group_state`` named in robot.yaml), (nq,).

    Joints the SRDF does not list keep Pinocchio's neutral value, except gripper joints,
    which take their ``open_position`` (robot.yaml). That matters when a posture leaves a
    gripper exactly on a joint limit (fully open), where a limit constraint or inequality task
    would already be active; open_position is just inside. Every value is then checked to lie
    within the joint limits.
    """
    desc = robot(name)
    if model is None:
        model, _ = load_pinocchio(name, with_collision=False)
        return np.array(model.referenceConfigurations[desc.reference])
    return configuration_from_srdf(model, desc.srdf.read_text(), desc.reference, semantics(name))


def configuration_from_srdf(model, srdf_text: str, state: str, sem: Semantics) -> np.ndarray:
    """``group_state`` ``state`` of ``srdf_text`` as a configuration of ``model`` (see
    :func:`reference_configuration`); raises KeyError or ValueError naming the problem."""
    import pinocchio as pin

    root = ET.fromstring(srdf_text)
    where = f"{model.name}: SRDF"
    states = {attribute(gs, "name", where): gs for gs in root.findall("group_state")}
    if state not in states:
        raise KeyError(f"{model.name}: SRDF has no group_state {state!r}, only {sorted(states)}")
    q = pin.neutral(model)
    listed = set()
    for j in states[state].findall("joint"):
        jname = attribute(j, "name", f"{where} state {state}")
        if not model.existJointName(jname):
            raise KeyError(f"{model.name}: SRDF state {state} names unknown joint {jname}")
        jm = model.joints[model.getJointId(jname)]
        where_joint = f"{where} state {state} joint {jname}"
        values = list(numbers(attribute(j, "value", where_joint), where_joint))
        if jm.nq == 2 and jm.nv == 1 and len(values) == 1:  # a continuous joint's angle
            values = [float(np.cos(values[0])), float(np.sin(values[0]))]
        if len(values) != jm.nq:
            raise ValueError(f"{model.name}: {jname} needs {jm.nq} values, SRDF gives {values}")
        q[jm.idx_q : jm.idx_q + jm.nq] = values
        listed.add(jname)
    for g in sem.grippers:  # (a gripper joint the model lacks: `marionette robot check` says so)
        if g.joint is not None and g.joint not in listed and model.existJointName(g.joint):
            q[model.joints[model.getJointId(g.joint)].idx_q] = g.open_position
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    bad = [
        model.names[j]
        for j in range(1, model.njoints)
        if model.joints[j].nq == 1
        and not lo[model.joints[j].idx_q] <= q[model.joints[j].idx_q] <= hi[model.joints[j].idx_q]
    ]
    if bad:
        raise ValueError(f"{model.name} {state}: joints outside their limits: {bad}")
    return pin.normalize(model, q)


@cache
def root_link(name: str | Path) -> str:
    """The URDF's root link of robot ``name`` (a free-flyer's base body)."""
    from marionette.models.urdf import read_urdf

    return read_urdf(robot(name).urdf).root


def semantics(name: str | Path) -> Semantics:
    """Grippers, contact surfaces and tags of robot ``name`` (its robot.yaml)."""
    d = robot(name).data
    grippers = [{k: v for k, v in g.items() if k != "jaws"} for g in d.get("grippers", [])]
    sections = {"name": d["name"], "grippers": grippers}
    sections.update({k: d[k] for k in ("contacts", "tags") if k in d})
    return semantics_from_dict(sections, str(robot(name).semantics))


@dataclass(frozen=True)
class MujocoJoint:
    """A hinge or slide of a robot's MJCF, in qpos order. ``mimic`` = (driver, multiplier,
    offset) when an ``<equality><joint>`` ties it to another joint (a URDF mimic joint that
    Pinocchio keeps fixed): q = multiplier * q_driver + offset."""

    name: str
    mimic: tuple[str, float, float] | None = None


def mujoco_layout(
    bodies: ET.Element, equalities: Iterable[ET.Element] | None = None
) -> tuple[MujocoJoint, ...]:
    """The hinges/slides under ``bodies`` (a <body> or <worldbody>) in document order (= qpos
    order), mimics from ``equalities`` (<joint joint1 joint2 polycoef> elements; default: the
    ``<equality>`` children of ``bodies`` itself when it is a <mujoco> element). Raises
    ValueError naming an element that lacks a name MuJoCo needs here."""
    if equalities is None:
        equalities = [e for eq in bodies.findall("equality") for e in eq]
    if bodies.tag == "mujoco":
        bodies = child(bodies, "worldbody", "MJCF")  # <equality> holds <joint> elements too
    ties = {}
    for e in equalities:
        driver = e.get("joint2")
        if e.tag == "joint" and driver:
            where = f"MJCF equality joint {driver}"
            a = numbers(e.get("polycoef", "0 1 0 0 0"), f"{where} polycoef", 5)
            ties[attribute(e, "joint1", where)] = (driver, a[1], a[0])
    joints = []
    for j in bodies.iter("joint"):
        name = attribute(j, "name", "MJCF: a joint (the controller maps joints by name)")
        joints.append(MujocoJoint(name, ties.get(name)))
    return tuple(joints)


@cache
def _robot_layout(name: str | Path) -> tuple[MujocoJoint, ...]:
    return mujoco_layout(ET.parse(robot(name).mjcf).getroot())


def pinocchio_to_mujoco(name: str | Path, q: np.ndarray, layout=None) -> np.ndarray:
    """MuJoCo ``qpos`` of the robot alone (model <robot>.xml) from Pinocchio ``q`` (nq,); mimic
    joints (MuJoCo only) get their driver's value through the mimic relation. ``layout``: the
    model's :func:`mujoco_layout` (default: models/<robot>/<robot>.xml)."""
    q = np.asarray(q, dtype=float)
    layout = _robot_layout(name) if layout is None else layout
    base = robot(name).base
    if base == "free_flyer":
        head, tail = np.concatenate([q[:3], q[[6, 3, 4, 5]]]), q[7:]
    elif base == "planar":
        head, tail = np.concatenate([q[:2], [np.arctan2(q[3], q[2])]]), q[4:]
        layout = layout[3:]  # root_x, root_y, root_yaw
    else:
        head, tail = np.zeros(0), q
    driven = [j.name for j in layout if j.mimic is None]
    if len(driven) != tail.size:
        raise ValueError(
            f"{name}: q has {tail.size} joint values after the base, the MJCF "
            f"{len(driven)} joints that are not mimics"
        )
    value = dict(zip(driven, tail))
    out = [
        value[j.name] if j.mimic is None else j.mimic[1] * value[j.mimic[0]] + j.mimic[2]
        for j in layout
    ]
    return np.concatenate([head, out])


def mujoco_to_pinocchio(name: str | Path, qpos: np.ndarray, layout=None) -> np.ndarray:
    """Pinocchio ``q`` from MuJoCo ``qpos`` of the robot alone (inverse of the above: mimic
    joints dropped)."""
    qpos = np.asarray(qpos, dtype=float)
    layout = _robot_layout(name) if layout is None else layout
    base = robot(name).base
    if base == "free_flyer":
        head, n_head = np.concatenate([qpos[:3], qpos[[4, 5, 6, 3]] / np.linalg.norm(qpos[3:7])]), 7
    elif base == "planar":
        head, n_head = np.array([qpos[0], qpos[1], np.cos(qpos[2]), np.sin(qpos[2])]), 3
        layout = layout[3:]
    else:
        head, n_head = np.zeros(0), 0
    tail = qpos[n_head:]
    if tail.size != len(layout):
        raise ValueError(
            f"{name}: qpos has {tail.size} joint values after the base, the MJCF "
            f"{len(layout)} joints"
        )
    return np.concatenate([head, [a for a, j in zip(tail, layout) if j.mimic is None]])


def mujoco_nq(name: str | Path) -> int:
    """Size of the robot's block of MuJoCo ``qpos`` (mimic joints included)."""
    return {"free_flyer": 7, "planar": 0, "fixed": 0}[robot(name).base] + len(_robot_layout(name))


# --- objects ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class ObjectModel:
    """An object loaded for planning: Pinocchio model (root ``root_joint``), collision
    model, and its handles, tags and contact surfaces."""

    name: str
    model: object  # pinocchio.Model
    collision_model: object  # pinocchio.GeometryModel
    semantics: Semantics


def object_names() -> list[str]:
    return sorted(p.stem for p in OBJECTS_DIR.glob("*.urdf"))


def object_urdf(name: str) -> Path:
    path = OBJECTS_DIR / f"{name}.urdf"
    if not path.exists():
        raise UnknownModel(f"unknown object {name!r}; known objects: {object_names()}")
    return path


def load_object(name: str, root: Literal["free_flyer", "fixed"] = "free_flyer") -> ObjectModel:
    """Object ``name`` (models/objects/<name>.urdf + .yaml) with a free-flyer or fixed root."""
    import pinocchio as pin

    urdf = str(object_urdf(name))
    if root == "free_flyer":
        model = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
    elif root == "fixed":
        model = pin.buildModelFromUrdf(urdf)
    else:
        raise ValueError(f"root must be 'free_flyer' or 'fixed', got {root!r}")
    model.name = name
    geom = pin.buildGeomFromUrdf(
        model, urdf, pin.GeometryType.COLLISION, package_dirs=package_dirs()
    )
    return ObjectModel(name, model, geom, load_semantics(OBJECTS_DIR / f"{name}.yaml"))


# --- helpers ---------------------------------------------------------------------------------


def _cmeel_prefix() -> Path:
    import sys

    candidates = [Path(p) / "cmeel.prefix" for p in sys.path if p.endswith("site-packages")]
    for c in candidates:
        if (c / "share" / "example-robot-data").is_dir():
            return c
    out = subprocess.run(
        [sys.executable, "-m", "cmeel", "cmake"], capture_output=True, text=True, check=True
    )
    return Path(out.stdout.strip())
