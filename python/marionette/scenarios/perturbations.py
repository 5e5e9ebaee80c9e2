"""Seeded perturbations of a scenario's trial: what vision and calibration must close (thesis 000
ch. 4-5; ``docs/scenarios.md``).

* **displacement before execution** — the object is moved on the table between planning and
  execution (uniform in a disc of ``displacement_m`` and a yaw within ``displacement_deg``);
* **slip during execution** — while carried, the object turns and shifts in the hand
  (``slip_m`` / ``slip_deg``): the weld is released, the object moved, the weld closed again,
  at the start of its last carry (after plank-flip's hand-over; ``slip_step`` names another
  step);
* **push during the carry** (friction grasps) — the held object is pushed by a force of
  ``push_n`` (1/2 to 1 of it, a random direction) for ``push_s``, 0 to 1 s after the grip
  settled in its first carry: the physics decides whether the grip holds it;
* **friction change during the carry** (friction grasps) — once the grip has settled in the
  first carry, the held object's surfaces take the sliding friction ``carry_friction`` in all
  their contacts (a box gone oily): below m g / (2 squeeze) it slips out of the fingers;
* **joint offsets** in the controller's model (ch. 4: encoder offsets, 7° shoulder, 4° wrist):
  the MuJoCo joint's ``ref`` is set to the offset, so the simulator reports q + offset for the
  true angle q and the controller's Pinocchio model places the links off by it;
* **camera noise** — Gaussian noise on each measured object pose, on top of the detection's
  own error on the rendered images (:class:`visual_servo.ServoOptions`).

Everything is drawn from ``numpy.random.default_rng(seed)``: a trial is reproducible from its seed.

The magnitudes (:class:`PerturbationSettings`) come from ``marionette demo --perturb``
(:func:`settings_from_argument`): a preset named by what it does (:data:`PRESETS`), a YAML file
(``perturbation.schema.json``), or magnitudes on the command line, ``key=value`` items after or
instead of presets (``--perturb all,displacement_m=0.08,joint_offsets_deg.arm_right_4_joint=6``).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin


@dataclass(frozen=True)
class PerturbationSettings:
    """Magnitudes (maxima for uniform draws, sigmas for noise); zero disables a perturbation."""

    displacement_m: float = 0.0
    displacement_deg: float = 0.0
    slip_m: float = 0.0
    slip_deg: float = 0.0
    slip_step: int | None = None  # None: the start of the object's last carry
    push_n: float = 0.0
    push_s: float = 0.1
    carry_friction: float = 0.0  # 0: unchanged
    joint_offsets_deg: dict[str, float] = field(default_factory=dict)  # joint -> |offset|
    camera_noise_m: float = 0.0
    camera_noise_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "displacement_m",
            "displacement_deg",
            "slip_m",
            "slip_deg",
            "push_n",
            "carry_friction",
            "camera_noise_m",
            "camera_noise_deg",
        ):
            if getattr(self, name) < 0:
                raise ValueError(f"perturbation {name} must be >= 0, got {getattr(self, name)}")
        if not self.push_s > 0:
            raise ValueError(f"perturbation push_s must be > 0 s, got {self.push_s}")


# `marionette demo --perturb NAME`: each part alone, and all of them (the set plank-flip's trials
# are judged under: docs/scenarios.md).
PARTS: dict[str, PerturbationSettings] = {
    # The object moved on the table between planning and execution.
    "displacement": PerturbationSettings(displacement_m=0.05, displacement_deg=10.0),
    # What the placement servo alone is built to close: the object disturbed in the hand — a
    # welded grasp slips (the weld moved), a friction grasp is pushed (the physics decides) —
    # and camera noise. Each trial takes the one its grasps can feel (:func:`acting_on`).
    "in-hand": PerturbationSettings(
        slip_m=0.01,
        slip_deg=5.0,
        push_n=5.0,
        push_s=0.1,
        camera_noise_m=0.002,
        camera_noise_deg=0.5,
    ),
    # Encoder offsets of both TALOS arms (ch. 4: 7° at the shoulder, 4° at the wrist).
    "joint-offsets": PerturbationSettings(
        joint_offsets_deg={
            "arm_left_1_joint": 7.0,
            "arm_left_7_joint": 4.0,
            "arm_right_1_joint": 7.0,
            "arm_right_7_joint": 4.0,
        }
    ),
}


def combined(parts: list[PerturbationSettings]) -> PerturbationSettings:
    """The perturbations of every part at once: each magnitude from the part that sets it
    (ValueError when two parts set the same one differently)."""
    out: dict[str, Any] = {}
    default = PerturbationSettings()
    for part in parts:
        for f in fields(PerturbationSettings):
            value = getattr(part, f.name)
            if value == getattr(default, f.name):
                continue
            if f.name in out and out[f.name] != value:
                raise ValueError(f"perturbation parts disagree on {f.name}: {out[f.name]}, {value}")
            out[f.name] = value
    return PerturbationSettings(**out)


PRESETS: dict[str, PerturbationSettings] = {
    "all": combined(list(PARTS.values())),
    **PARTS,
    # A bump on the held object during the carry (friction grasps only: a weld would not feel it).
    "push": PerturbationSettings(push_n=5.0, push_s=0.1),
    # The held object gone slippery during the carry (friction grasps only): at 0.25 a 5 N squeeze
    # per finger holds 0.25 kg against gravity (Coulomb), less than a 0.3 kg box.
    "slippery": PerturbationSettings(carry_friction=0.25),
}


def settings_from_document(doc: Any, source: str = "<perturbation>") -> PerturbationSettings:
    """The magnitudes of a perturbation document (perturbation.schema.json; ``description``
    ignored); :class:`marionette.schemas.DataFileError` naming the bad key otherwise."""
    from marionette.schemas import validate

    validate(doc, "perturbation", source)
    values = {k: v for k, v in doc.items() if k != "description"}
    if "joint_offsets_deg" in values:
        values["joint_offsets_deg"] = {
            str(j): float(m) for j, m in values["joint_offsets_deg"].items()
        }
    return PerturbationSettings(**values)


def load_settings(path: str | Path) -> PerturbationSettings:
    """The magnitudes of a perturbation YAML file (perturbation.schema.json)."""
    from marionette.schemas import load_validated

    return settings_from_document(load_validated(path, "perturbation") or {}, str(path))


def _number(key: str, text: str) -> float | int:
    try:
        return int(text) if key == "slip_step" else float(text)
    except ValueError:
        raise ValueError(f"--perturb: {key}={text!r} is not a number") from None


def settings_from_argument(text: str) -> PerturbationSettings | None:
    """``--perturb``: ``none`` (None); a YAML file; or comma-separated items, each a preset of
    :data:`PRESETS` (combined) or a magnitude ``key=value`` of perturbation.schema.json that
    replaces the presets' (``joint_offsets_deg.JOINT=deg`` for one joint). ValueError, or
    DataFileError for a file or a key, with one line naming the bad item."""
    text = text.strip()
    if text == "none":
        return None
    if text.endswith((".yaml", ".yml")) or Path(text).is_file():
        return load_settings(text)
    presets, values = [], {}
    offsets: dict[str, float] = {}
    for item in filter(None, (i.strip() for i in text.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            if item not in PRESETS:
                raise ValueError(
                    f"--perturb: no preset {item!r} (presets: none, {', '.join(PRESETS)}; or "
                    "key=value magnitudes, or a YAML file)"
                )
            presets.append(PRESETS[item])
        elif key.startswith("joint_offsets_deg."):
            offsets[key.split(".", 1)[1]] = _number(key, value)
        else:
            values[key] = _number(key, value)
    base = combined(presets) if presets else PerturbationSettings()
    doc: dict[str, Any] = {
        f.name: getattr(base, f.name)
        for f in fields(PerturbationSettings)
        if getattr(base, f.name) != getattr(PerturbationSettings(), f.name)
    }
    doc.update(values)
    if offsets:
        doc["joint_offsets_deg"] = {**doc.get("joint_offsets_deg", {}), **offsets}
    return settings_from_document(doc, "--perturb")


@dataclass(frozen=True)
class Perturbation:
    """One trial's draw: table displacement (dx, dy [m], dyaw [rad]), slip in the hand (a twist
    of the object frame, (v, w) [m, rad]), joint offsets [rad], camera noise sigmas, the push
    during the carry (force [N], duration [s], delay after the grip settled [s]), the object's
    friction coefficient from its first carry on (0: unchanged)."""

    seed: int
    displacement: tuple[float, float, float]
    slip: tuple[float, ...]
    slip_step: int | None
    joint_offsets: dict[str, float]
    camera_noise_m: float
    camera_noise_rad: float
    push: tuple[float, float, float] = (0.0, 0.0, 0.0)
    push_s: float = 0.0
    push_delay_s: float = 0.0
    carry_friction: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["displacement_mm_deg"] = [
            1e3 * self.displacement[0],
            1e3 * self.displacement[1],
            math.degrees(self.displacement[2]),
        ]
        d["joint_offsets_deg"] = {k: math.degrees(v) for k, v in self.joint_offsets.items()}
        return d

    @property
    def any(self) -> bool:
        return bool(
            any(self.displacement)
            or any(self.slip)
            or self.joint_offsets
            or self.camera_noise_m
            or self.camera_noise_rad
            or any(self.push)
            or self.carry_friction
        )


def draw(settings: PerturbationSettings, seed: int) -> Perturbation:
    """The perturbation of the trial with ``seed``."""
    rng = np.random.default_rng(seed)
    r = settings.displacement_m * math.sqrt(rng.uniform())  # uniform in the disc
    a = rng.uniform(0.0, 2 * math.pi)
    yaw = math.radians(settings.displacement_deg) * rng.uniform(-1.0, 1.0)
    v = rng.normal(size=3)
    w = rng.normal(size=3)
    v *= settings.slip_m * rng.uniform(0.5, 1.0) / max(float(np.linalg.norm(v)), 1e-12)
    w *= (
        math.radians(settings.slip_deg)
        * rng.uniform(0.5, 1.0)
        / max(float(np.linalg.norm(w)), 1e-12)
    )
    offsets = draw_joint_offsets(rng, settings.joint_offsets_deg)
    # Drawn last: the draws above stay those of earlier versions for the same seed.
    push = rng.normal(size=3)
    push *= settings.push_n * rng.uniform(0.5, 1.0) / max(float(np.linalg.norm(push)), 1e-12)
    push_delay = rng.uniform(0.0, 1.0)
    return Perturbation(
        seed,
        (r * math.cos(a), r * math.sin(a), yaw),
        tuple(map(float, [*v, *w])),
        settings.slip_step,
        offsets,
        settings.camera_noise_m,
        math.radians(settings.camera_noise_deg),
        (float(push[0]), float(push[1]), float(push[2])),
        settings.push_s if settings.push_n else 0.0,
        float(push_delay) if settings.push_n else 0.0,
        settings.carry_friction,
    )


def acting_on(p: Perturbation, friction_grasps: bool) -> tuple[Perturbation, str | None]:
    """``p`` with only the in-hand perturbations grasps of that kind feel: a slip moves a weld
    (welded grasps); a push and a friction change act through the contacts (friction grasps).
    Also a one-line note naming what was left out (None when nothing was)."""
    if friction_grasps and any(p.slip):
        kept = dataclasses.replace(p, slip=(0.0,) * 6)
        return kept, "the slip moves welds; this trial's grasps hold by friction: not applied"
    if not friction_grasps and (any(p.push) or p.carry_friction):
        kept = dataclasses.replace(
            p, push=(0.0, 0.0, 0.0), push_s=0.0, push_delay_s=0.0, carry_friction=0.0
        )
        return (
            kept,
            "a push or a friction change acts on friction grasps; this trial welds: not applied",
        )
    return p, None


def draw_joint_offsets(rng: np.random.Generator, offsets_deg: dict[str, float]) -> dict[str, float]:
    """Joint -> encoder offset [rad]: each nonzero magnitude of ``offsets_deg`` [deg] with a sign
    drawn from ``rng`` (joints in name order)."""
    return {
        j: math.radians(m) * float(rng.choice([-1.0, 1.0]))
        for j, m in sorted(offsets_deg.items())
        if m
    }


def draw_displacement(
    rng: np.random.Generator, max_translation_m: float, max_rotation_deg: float, centre: np.ndarray
) -> pin.SE3:
    """Seeded displacement D of a workpiece, applied as X_true = X_nominal D: a rotation of at most
    ``max_rotation_deg`` about a random axis through ``centre`` (workpiece frame) and a
    translation of at most ``max_translation_m``; both magnitudes uniform in [1/2, 1] of their
    bound."""

    def unit():
        v = rng.normal(size=3)
        return v / np.linalg.norm(v)

    angle = np.radians(max_rotation_deg) * rng.uniform(0.5, 1.0)
    R = pin.exp3(angle * unit())
    t = max_translation_m * rng.uniform(0.5, 1.0) * unit()
    # rotation about the centre, then translation: p -> R (p - c) + c + t
    return pin.SE3(R, centre - R @ centre + t)


def displaced(X_WO: pin.SE3, displacement: tuple[float, float, float]) -> pin.SE3:
    """The object moved on the table: translated in x, y and turned about the world z through
    its own origin (it stays on its face)."""
    dx, dy, dyaw = displacement
    R = pin.rpy.rpyToMatrix(0.0, 0.0, dyaw)
    return pin.SE3(R @ X_WO.rotation, X_WO.translation + np.array([dx, dy, 0.0]))


def slipped(X_WO: pin.SE3, slip: tuple[float, ...]) -> pin.SE3:
    """The object after slipping in the hand by the twist ``slip`` in its own frame."""
    return X_WO * pin.exp6(np.asarray(slip, dtype=float))


def mjcf_pose_attributes(X: pin.SE3) -> str:
    """``pos="..." quat="..."`` of an MJCF body at ``X`` (MuJoCo's quaternion order w x y z)."""
    q = pin.Quaternion(X.rotation)
    return (
        f'pos="{" ".join(f"{v:.12g}" for v in X.translation)}" '
        f'quat="{q.w:.12g} {q.x:.12g} {q.y:.12g} {q.z:.12g}"'
    )


def mjcf_pose(attributes: str) -> pin.SE3:
    """The pose in the ``pos``/``quat`` attributes of an MJCF element (identity for the missing
    ones): the inverse of :func:`mjcf_pose_attributes`."""
    pos = re.search(r'pos="([^"]+)"', attributes)
    quat = re.search(r'quat="([^"]+)"', attributes)
    w, x, y, z = (float(v) for v in quat.group(1).split()) if quat else (1.0, 0.0, 0.0, 0.0)
    return pin.SE3(
        pin.Quaternion(w, x, y, z).normalized().matrix(),
        np.array(pos.group(1).split(), dtype=float) if pos else np.zeros(3),
    )


def place_mocap_body(mjcf: str, name: str, X: pin.SE3) -> str:
    """MJCF text with mocap body ``name`` at ``X``: its ``pos``/``quat`` and its entries of every
    keyframe's ``mpos``/``mquat`` (MuJoCo resets mocap bodies to the keyframe's values: changing
    the body alone leaves the simulated workpiece at its nominal pose). ValueError when the
    scene has no such mocap body."""
    mocaps = re.findall(r'<body name="([^"]+)"[^>]*mocap="true"', mjcf)
    if name not in mocaps:
        raise ValueError(f"no mocap body {name!r} in the scene (mocap bodies: {mocaps})")
    i = mocaps.index(name)
    q = pin.Quaternion(X.rotation)
    pos, quat = list(X.translation), [q.w, q.x, q.y, q.z]
    mjcf = re.sub(
        rf'<body name="{re.escape(name)}" [^>]*mocap="true">',
        f'<body name="{name}" {mjcf_pose_attributes(X)} mocap="true">',
        mjcf,
    )

    def put(values: list[float]) -> Callable[[list[str]], None]:
        def edit(v: list[str]) -> None:
            n = len(values)
            v[n * i : n * (i + 1)] = [f"{x:.12g}" for x in values]

        return edit

    return _edit_keyframes(mjcf, {"mpos": put(pos), "mquat": put(quat)})


def _edit_keyframes(mjcf: str, edits: dict[str, Callable[[list[str]], None]]) -> str:
    """MJCF text whose keyframes' vector attributes named in ``edits`` (``qpos``, ``ctrl``,
    ``mpos``...) are changed in place by their edit, which gets the values as strings."""

    def key(m: re.Match) -> str:
        text = m.group(0)
        for attr, edit in edits.items():
            a = re.search(rf' {attr}="([^"]+)"', text)
            if a is None:
                continue
            v = a.group(1).split()
            edit(v)
            text = text.replace(a.group(0), f' {attr}="{" ".join(v)}"')
        return text

    return re.sub(r"<key [^>]*/>", key, mjcf)


def set_keyframe_joints(mjcf: str, positions: dict[str, float]) -> str:
    """MJCF text whose keyframes start the 1-dof joints named in ``positions`` there: their
    ``qpos`` entries and their position servos' ``ctrl`` targets (a robot that starts the trial
    in that posture, e.g. its head looking down). ValueError naming a joint the scene has not
    as a hinge or slide joint."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(mjcf)
    world = root.find("worldbody")
    if world is None:
        raise ValueError("the scene has no worldbody")
    sizes = {"free": 7, "ball": 4, "hinge": 1, "slide": 1}
    address: dict[str, int] = {}
    qpos = 0
    for element in world.iter():
        if element.tag == "freejoint":
            qpos += 7
        elif element.tag == "joint":
            kind = element.get("type", "hinge")
            if kind in ("hinge", "slide"):
                address[str(element.get("name"))] = qpos
            qpos += sizes[kind]
    actuators = root.find("actuator")
    servo = {
        str(a.get("joint")): i for i, a in enumerate(actuators if actuators is not None else [])
    }
    unknown = sorted(set(positions) - set(address))
    if unknown:
        raise ValueError(f"the scene has no hinge or slide joint {', '.join(unknown)}")

    def put(index: dict[str, int]) -> Callable[[list[str]], None]:
        def edit(v: list[str]) -> None:
            for joint, value in positions.items():
                if joint in index:
                    v[index[joint]] = f"{float(value):.12g}"

        return edit

    return _edit_keyframes(mjcf, {"qpos": put(address), "ctrl": put(servo)})


def write_scene(text: str, source: Path, out: Path) -> Path:
    """Writes the MJCF ``text`` of scene ``source`` to ``out``, its asset folders (``meshdir``,
    ``texturedir``, relative to ``source``) made absolute so that it loads from anywhere."""
    base = source.resolve().parent
    text = re.sub(
        r'(meshdir|texturedir)="([^"]*)"',
        lambda m: f'{m.group(1)}="{(base / m.group(2)).resolve()}"',
        text,
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    return out


def _joint_pattern(joint: str) -> re.Pattern:
    return re.compile(r'(<joint name="' + re.escape(joint) + r'"[^>]*?)(\s*/>)')


def missing_joints(scene: Path, joints: list[str]) -> list[str]:
    """The ``joints`` the MJCF ``scene`` has no joint element of (none can be offset)."""
    text = Path(scene).read_text()
    return [j for j in joints if not _joint_pattern(j).search(text)]


def _shifted_range(tag: str, attribute: str, offset: float) -> str:
    """``tag`` (an element's opening text) with both bounds of ``attribute="lo hi"`` moved by
    ``offset``; unchanged without the attribute."""

    def shift(m: re.Match[str]) -> str:
        lo, hi = (float(v) + offset for v in m.group(2).split())
        return f'{m.group(1)}"{lo:.9f} {hi:.9f}"'

    return re.sub(r"(\b" + attribute + r'=)"([^"]*)"', shift, tag, count=1)


def _position_actuator_pattern(joint: str) -> re.Pattern:
    """A position servo on ``joint``: ``<position>``, or ``<general>`` with an affine bias (the
    MJCF the models are generated with); a motor's ctrlrange is a torque and is left alone."""
    return re.compile(
        r'<(?:position\b|general\b(?=[^>]*\bbiastype="affine"))[^>]*\bjoint="'
        + re.escape(joint)
        + r'"[^>]*>'
    )


def scene_with_joint_offsets(scene: Path, offsets: dict[str, float], out: Path) -> Path:
    """A copy of the MJCF ``scene`` in which each joint of ``offsets`` has ``ref`` = offset [rad]
    (the simulator then reports q + offset), written to ``out``; asset paths made absolute.

    What the simulator reports includes the offset, and so do MJCF joint ranges and position
    servo ctrlranges (they are in qpos units): both move by the offset too, so that the joint's
    physical stops stay at the same true angles, as on a robot whose encoder is off. (Left
    unmoved, a 7 deg offset moved TALOS' shoulder stop 7 deg into the plan's motion, and the arm
    stalled against it.)"""
    text = scene.read_text()
    for joint, offset in offsets.items():

        def with_ref(m: re.Match[str], offset: float = offset) -> str:
            opening = _shifted_range(m.group(1), "range", offset)
            return f'{opening} ref="{offset:.9f}"{m.group(2)}'

        text, n = _joint_pattern(joint).subn(with_ref, text, count=1)
        if n != 1:
            raise ValueError(f"{scene}: no joint {joint!r} to offset")

        def servo_range(m: re.Match[str], offset: float = offset) -> str:
            return _shifted_range(m.group(0), "ctrlrange", offset)

        text = _position_actuator_pattern(joint).sub(servo_range, text)
    return write_scene(text, scene, out)


def true_configuration(
    model: pin.Model, q_encoders: np.ndarray, joint_offsets: dict[str, float]
) -> np.ndarray:
    """The robot's configuration from encoders that read q + offset
    (:func:`scene_with_joint_offsets`)."""
    q = q_encoders.copy()
    for joint, offset in joint_offsets.items():
        q[model.joints[model.getJointId(joint)].idx_q] -= offset
    return q
