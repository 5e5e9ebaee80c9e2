"""Controller specs: the declarative task stacks marionette-controller builds and swaps in.

A :class:`ControllerSpec` is what the controller factory (plan -> controllers) writes to its
human-readable file and what the supervisor sends on CONTROLLER_SPEC; it converts to and from
``lcmt_controller_spec`` and plain dicts (YAML/JSON). Task kinds and reference layouts are those
of cpp/include/marionette/controller/controller_factory.h:

============  ==========================================  ==========  ==========
kind          controlled quantity                          reference   derivative
============  ==========================================  ==========  ==========
se3, pbvs     pose of ``frame`` in world                   7 (x y z qw qx qy qz)  6
relative_se3  pose of ``frame`` relative to ``frame_b``    7           6
position      origin of ``frame`` in world                 3           3
com           centre of mass                               3           3
posture       joints (``joints``, empty = all 1-dof)       nq          nv
gaze          world point kept at the image centre         3           3
gripper_      one gripper joint (``joints``): position,    1 (target)  1
admittance    then force (``parameters``, thesis 000 eq. 3.11-3.13, gripper_admittance_spec.h)
============  ==========================================  ==========  ==========

An empty fixed reference means "hold the current value"; ``streamed=True`` makes the task follow
references streamed on TASK_REFERENCE under the task's name; ``reference_channel="walk:<role>"``
takes the reference from the controller's own pattern generator (Dang 2012 §2.6: the footstep
manager + ZMP preview control fed by FOOTSTEP_PLAN), see :data:`WALK_REFERENCES`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from marionette import channels, lcmt_controller_spec, lcmt_task_reference, lcmt_task_spec
from marionette.models.semantics import GRIPPER_ADMITTANCE_PARAMETERS

KINDS = ("se3", "pbvs", "relative_se3", "position", "com", "posture", "gaze", "gripper_admittance")
# Walking references produced inside the controller (controller_factory.cc, ConnectWalkReference):
# reference_channel -> the task kind it feeds. Both feet are needed for a walk (the soles it
# starts from); the CoM and the waist (turning with the feet's mean yaw) are optional.
WALK_REFERENCES = {
    "walk:left_foot": "se3",
    "walk:right_foot": "se3",
    "walk:com": "com",
    "walk:waist": "se3",
}
# The id the controller's own hold controller reports as active once repeated time-budget
# overruns engaged it (cpp/include/marionette/controller/hold_controller.h).
HOLD_CONTROLLER_ID = -2


class SpecError(ValueError):
    """A spec that the controller would refuse; the message says which task and why."""


@dataclass
class TaskSpec:
    name: str
    kind: str
    priority: int
    frame: str = ""
    frame_b: str = ""
    mask: Sequence[bool] = ()  # empty = every component
    gain: float = 2.0  # lambda [1/s] (at zero error when adaptive)
    gain_max: float = 0.0  # adaptive gain at large error (0 = constant)
    gain_slope: float = 0.0  # adaptive slope (0 = constant)
    streamed: bool = False  # follow TASK_REFERENCE chunks named after the task
    reference: Sequence[float] = ()  # fixed reference (empty = hold the current value)
    joints: Sequence[str] = ()  # posture joints (empty = all)
    reference_channel: str = ""  # "walk:left_foot|right_foot|com|waist": from the walk (module)
    parameters: dict[str, float] = field(default_factory=dict)  # kind-specific (gripper_admittance)

    def check(self) -> None:
        where = f"task {self.name!r}"
        if not self.name or any(c in self.name for c in ". "):
            raise SpecError(f"{where}: a task needs a name without spaces or dots")
        if self.kind not in KINDS:
            raise SpecError(f"{where}: unknown kind {self.kind!r} (one of {', '.join(KINDS)})")
        if self.kind in ("se3", "pbvs", "relative_se3", "position", "gaze") and not self.frame:
            raise SpecError(f"{where}: a {self.kind} task needs a frame")
        if self.kind == "relative_se3" and not self.frame_b:
            raise SpecError(f"{where}: a relative_se3 task needs frame_b")
        if len(self.mask) > 6:
            raise SpecError(f"{where}: a mask has at most 6 entries")
        if (
            not np.all(np.isfinite([self.gain, self.gain_max, self.gain_slope]))
            or min(self.gain, self.gain_max, self.gain_slope) < 0
        ):
            raise SpecError(f"{where}: gains must be finite and >= 0")
        if not np.all(np.isfinite(np.asarray(self.reference, dtype=float))):
            raise SpecError(f"{where}: non-finite reference")
        if self.parameters and self.kind != "gripper_admittance":
            raise SpecError(f"{where}: only gripper_admittance tasks take parameters")
        if self.kind == "gripper_admittance":
            unknown = sorted(set(self.parameters) - set(GRIPPER_ADMITTANCE_PARAMETERS))
            if unknown:
                raise SpecError(
                    f"{where}: unknown parameters {unknown} "
                    f"(one of {', '.join(GRIPPER_ADMITTANCE_PARAMETERS)})"
                )
            if (
                len(self.joints) != 1
                or len(self.reference) != 1
                or self.streamed
                or self.gain_slope
            ):
                raise SpecError(
                    f"{where}: a gripper_admittance task needs one joint, its position "
                    "target as a 1-value fixed reference and a constant gain"
                )
        if self.reference_channel:
            kind = WALK_REFERENCES.get(self.reference_channel)
            if kind is None:
                raise SpecError(
                    f"{where}: unknown reference_channel {self.reference_channel!r} "
                    f"(one of {', '.join(WALK_REFERENCES)}; streamed=True for "
                    f"{channels.TASK_REFERENCE})"
                )
            if self.kind != kind:
                raise SpecError(
                    f"{where}: a {self.reference_channel!r} reference needs a {kind} "
                    f"task, not {self.kind}"
                )
            if self.streamed or len(self.reference):
                raise SpecError(
                    f"{where}: a {self.reference_channel!r} task takes its reference "
                    "from the walk: no streamed or fixed reference"
                )

    def to_lcm(self) -> lcmt_task_spec:
        self.check()
        msg = lcmt_task_spec()
        msg.name = self.name
        msg.kind = self.kind
        msg.priority = int(self.priority)
        msg.frame = self.frame
        msg.frame_b = self.frame_b
        mask = list(self.mask) + [False] * (6 - len(self.mask))
        msg.mask = [bool(m) for m in mask]
        msg.gain = float(self.gain)
        msg.gain_max = float(self.gain_max)
        msg.gain_slope = float(self.gain_slope)
        msg.reference_channel = self.reference_channel or (
            channels.TASK_REFERENCE if self.streamed else ""
        )
        msg.reference = [float(x) for x in self.reference]
        msg.num_reference = len(msg.reference)
        msg.joint_name = list(self.joints)
        msg.num_joints = len(msg.joint_name)
        msg.parameter_name = list(self.parameters)
        msg.parameter_value = [float(v) for v in self.parameters.values()]
        msg.num_parameters = len(msg.parameter_name)
        return msg

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "kind": self.kind, "priority": self.priority}
        for key in ("frame", "frame_b"):
            if getattr(self, key):
                d[key] = getattr(self, key)
        if self.mask:
            d["mask"] = [bool(m) for m in self.mask]
        d["gain"] = self.gain
        if self.gain_slope:
            d.update(gain_max=self.gain_max, gain_slope=self.gain_slope)
        if self.streamed:
            d["streamed"] = True
        if len(self.reference):
            d["reference"] = [float(x) for x in self.reference]
        if self.joints:
            d["joints"] = list(self.joints)
        if self.reference_channel:
            d["reference_channel"] = self.reference_channel
        if self.parameters:
            d["parameters"] = {k: float(v) for k, v in self.parameters.items()}
        return d

    @classmethod
    def from_lcm(cls, msg: lcmt_task_spec) -> TaskSpec:
        """The inverse of :meth:`to_lcm` (TASK_REFERENCE -> ``streamed``); checked."""
        channel = msg.reference_channel
        streamed = channel == channels.TASK_REFERENCE
        mask = tuple(bool(m) for m in msg.mask)
        spec = cls(
            msg.name,
            msg.kind,
            int(msg.priority),
            frame=msg.frame,
            frame_b=msg.frame_b,
            mask=mask if any(mask) else (),
            gain=msg.gain,
            gain_max=msg.gain_max,
            gain_slope=msg.gain_slope,
            streamed=streamed,
            reference=tuple(msg.reference),
            joints=tuple(msg.joint_name),
            reference_channel="" if streamed else channel,
            parameters=dict(zip(msg.parameter_name, msg.parameter_value)),
        )
        spec.check()
        return spec

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TaskSpec:
        known = set(cls.__dataclass_fields__)
        unknown = set(d) - known
        if unknown:
            raise SpecError(f"task {d.get('name')!r}: unknown fields {sorted(unknown)}")
        return cls(**d)


@dataclass
class ControllerSpec:
    controller_id: int
    name: str
    tasks: list[TaskSpec] = field(default_factory=list)
    max_switch_velocity_jump: float = 0.1  # [rad/s] refuse a swap whose joint command jumps more
    reference_timeout: float = 0.1  # [s] watchdog on streamed references

    def check(self) -> None:
        if not self.tasks:
            raise SpecError(f"controller {self.name!r}: no task")
        names = [t.name for t in self.tasks]
        if len(set(names)) != len(names):
            raise SpecError(f"controller {self.name!r}: duplicate task names {names}")
        for t in self.tasks:
            t.check()

    def to_lcm(self, utime: int = 0) -> lcmt_controller_spec:
        self.check()
        msg = lcmt_controller_spec()
        msg.utime = int(utime)
        msg.controller_id = int(self.controller_id)
        msg.name = self.name
        msg.max_switch_velocity_jump = float(self.max_switch_velocity_jump)
        msg.reference_timeout = float(self.reference_timeout)
        msg.tasks = [t.to_lcm() for t in self.tasks]
        msg.num_tasks = len(msg.tasks)
        return msg

    def to_dict(self) -> dict[str, Any]:
        return {
            "controller_id": self.controller_id,
            "name": self.name,
            "max_switch_velocity_jump": self.max_switch_velocity_jump,
            "reference_timeout": self.reference_timeout,
            "tasks": [t.to_dict() for t in self.tasks],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ControllerSpec:
        tasks = [TaskSpec.from_dict(t) for t in d.get("tasks", [])]
        rest = {k: v for k, v in d.items() if k != "tasks"}
        return cls(tasks=tasks, **rest)


def reference_chunk(
    controller_id: int,
    task_name: str,
    start_utime: int,
    values: np.ndarray,
    derivatives: np.ndarray | None = None,
    dt_us: int = 1000,
    last: bool = False,
    sequence: int = 0,
) -> lcmt_task_reference:
    """An ``lcmt_task_reference`` of ``values`` (N x k) sampled every ``dt_us`` from
    ``start_utime`` (controller time), with optional feed-forward ``derivatives`` (N x m).
    ``sequence`` 0 starts a reference (or stands alone); n > 0 says the chunk follows chunk n - 1
    of the same reference, so that the controller refuses it when that one was lost."""
    values = np.atleast_2d(np.asarray(values, dtype=float))
    msg = lcmt_task_reference()
    msg.utime = int(start_utime)
    msg.task_name = task_name
    msg.controller_id = int(controller_id)
    msg.dt_us = int(dt_us)
    msg.num_samples, msg.value_size = values.shape
    msg.value = values.tolist()
    if derivatives is None:
        msg.derivative_size = 0
        msg.derivative = [[] for _ in range(msg.num_samples)]
    else:
        derivatives = np.atleast_2d(np.asarray(derivatives, dtype=float))
        if derivatives.shape[0] != msg.num_samples:
            raise SpecError(
                f"{task_name}: {derivatives.shape[0]} derivatives for {msg.num_samples} values"
            )
        msg.derivative_size = derivatives.shape[1]
        msg.derivative = derivatives.tolist()
    msg.last_chunk = bool(last)
    msg.sequence = int(sequence)
    return msg
