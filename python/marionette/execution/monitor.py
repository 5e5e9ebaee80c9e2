"""Execution monitor (thesis 000 §3.4.4.1 "failures' detection"): watches perception while the
supervisor runs and raises ``left_manifold`` when the world has left the current step's state
manifold — an object slid in (or fell from) the gripper that holds it, or an object that should
rest where it is placed moved.

The constraint residual of a step, from OBJECT_POSES (X_WO, perception) and ROBOT_STATE (q):

* held grasp (gripper g holds handle h of object o all along the step, ``Step.grasps``): the
  grasp constraint fixes the object in the gripper frame, X_GO = X_WG(q)^-1 X_WO, so the residual
  is the motion of X_GO since the grasp was first seen held, Δ = X_GO,0^-1 X_GO;
* placed object (no gripper on it in the step): its placement constraint fixes X_WO, so the
  residual is the motion of X_WO since the step started (objects released at this step's start
  are skipped for the step: they settle when the simulated weld lets go).

The residual is (‖Δp‖ [m], angle of ΔR [rad]); above ``position_tolerance`` or
``angle_tolerance`` in ``consecutive`` messages in a row (one noisy detection is not a failure)
the monitor publishes ``left_manifold`` on SUPERVISOR_EVENT (source ``monitor``, detail naming
the object, the constraint and the residual, value = ‖Δp‖); the supervisor then fails the step
and holds the robot (``decisions.FAILURES``). Recovery (re-estimation, replanning) is left to the
operator, as §3.4.4.1 advises for a fall.

:class:`ExecutionMonitor` is the pure computation (fed messages, returns the event);
:class:`MonitorNode` wires it to a bus beside a :class:`~marionette.execution.supervisor.Supervisor`
(it follows the current step from SUPERVISOR_STATE).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import channels, lcmt_object_poses, lcmt_robot_state, lcmt_supervisor_state
from marionette.control.client import configuration_from_state
from marionette.execution.decisions import event_message
from marionette.execution.factory import FactoryContext
from marionette.execution.plan_steps import Step
from marionette.execution.step_follower import StepFollower
from marionette.lcm_bus import LcmBus

SOURCE = "monitor"


@dataclass
class MonitorOptions:
    position_tolerance: float = 0.02  # [m] (the end check's pose tolerance, factory.END_THRESHOLDS)
    angle_tolerance: float = 0.1  # [rad] ~6 deg
    consecutive: int = 3  # messages above tolerance in a row


@dataclass
class Residual:
    """One constraint's residual: which object, which constraint, how far."""

    object_name: str
    constraint: str  # "grasp <gripper>" or "placement"
    position: float  # [m]
    angle: float  # [rad]

    def describe(self) -> str:
        return (
            f"{self.object_name} left its {self.constraint}: moved {self.position * 1e3:.1f} mm, "
            f"{np.degrees(self.angle):.1f} deg"
        )


@dataclass
class _Latch:
    X_ref: pin.SE3  # X_GO (grasp) or X_WO (placement) when first seen
    above: int = 0  # consecutive messages above tolerance


def pose_from_message(p: Any) -> pin.SE3:
    """X_WO of an ``lcmt_object_pose`` (world fields)."""
    w, x, y, z = p.quaternion_world
    return pin.SE3(
        pin.Quaternion(w, x, y, z).normalized().matrix(), np.array(p.position_world, dtype=float)
    )


def residual_of(X_ref: pin.SE3, X_now: pin.SE3) -> tuple[float, float]:
    """(‖Δp‖, ‖log ΔR‖) of Δ = X_ref^-1 X_now."""
    delta = X_ref.actInv(X_now)
    return float(np.linalg.norm(delta.translation)), float(np.linalg.norm(pin.log3(delta.rotation)))


@dataclass
class ExecutionMonitor:
    """The residual computation of the module docstring. Feed it :meth:`begin_step`,
    :meth:`on_state` and :meth:`on_object_poses`; the latter returns the residual that crossed the
    tolerance ``consecutive`` times (once per step), else None."""

    model: pin.Model
    ctx: FactoryContext
    options: MonitorOptions = field(default_factory=MonitorOptions)

    def __post_init__(self) -> None:
        self.data = self.model.createData()
        self.step: Step | None = None
        self.q: np.ndarray | None = None
        self._grasp_latches: dict[tuple[str, str], _Latch] = {}  # (gripper, object) -> latch
        self._placement_latches: dict[str, _Latch] = {}
        self._fired = False
        self.max_residual: dict[str, tuple[float, float]] = {}  # per object, this run

    def _object(self, handle: str) -> str:
        return self.ctx.handle_objects.get(handle, handle.split("/")[0])

    def begin_step(self, step: Step | None) -> None:
        """A new FSM state: grasps still held keep their reference, placements restart (None:
        no step runs, nothing is checked until one does)."""
        self.step = step
        if step is None:
            return
        held = {(g, self._object(h)) for g, h in step.grasps.items()}
        self._grasp_latches = {k: v for k, v in self._grasp_latches.items() if k in held}
        self._placement_latches = {}
        self.step = step
        self._fired = False

    def on_state(self, state: Any) -> None:
        """q from an ``lcmt_robot_state``."""
        self.on_configuration(configuration_from_state(self.model, state))

    def on_configuration(self, q: np.ndarray) -> None:
        self.q = np.asarray(q, dtype=float)

    def on_object_poses(self, msg: Any) -> Residual | None:
        if self.step is None or self.q is None or self._fired:
            return None
        step = self.step
        pin.framesForwardKinematics(self.model, self.data, self.q)
        held = {self._object(h): g for g, h in step.grasps.items()}
        touched = {
            self._object(h)
            for d in (
                step.grasps_from,
                step.grasps_to,
                step.parent_grasps_from,
                step.parent_grasps_to,
            )
            for h in d.values()
        }
        released = {self._object(h) for h in step.released.values()}
        worst: Residual | None = None
        for p in msg.objects:
            name = p.object_name
            X_WO = pose_from_message(p)
            if name in held:
                gripper = held[name]
                X_WG = self.data.oMf[self.model.getFrameId(self.ctx.gripper_frames[gripper])]
                X = X_WG.actInv(X_WO)
                latch = self._grasp_latches.setdefault((gripper, name), _Latch(X))
                constraint = f"grasp by {gripper}"
            elif name in touched or name in released:
                continue  # being grasped or let go in this step: no fixed constraint to check
            else:
                X = X_WO
                latch = self._placement_latches.setdefault(name, _Latch(X))
                constraint = "placement"
            position, angle = residual_of(latch.X_ref, X)
            best = self.max_residual.get(name, (0.0, 0.0))
            self.max_residual[name] = (max(best[0], position), max(best[1], angle))
            if position > self.options.position_tolerance or angle > self.options.angle_tolerance:
                latch.above += 1
                if latch.above >= self.options.consecutive and (
                    worst is None or position > worst.position
                ):
                    worst = Residual(name, constraint, position, angle)
            else:
                latch.above = 0
        if worst is not None:
            self._fired = True
        return worst


class MonitorNode:
    """Runs an :class:`ExecutionMonitor` on ``bus``: the step from SUPERVISOR_STATE (index into
    ``steps``), q from ROBOT_STATE, residuals on OBJECT_POSES; publishes ``left_manifold``."""

    def __init__(self, bus: LcmBus, monitor: ExecutionMonitor, steps: list[Step]) -> None:
        self.bus = bus
        self.monitor = monitor
        self.events: list[tuple[int, Residual]] = []
        self._lock = threading.Lock()
        self._follower = StepFollower(steps, monitor.begin_step)
        self._subscriptions = [
            bus.subscribe(channels.SUPERVISOR_STATE, lcmt_supervisor_state, self._on_supervisor),
            bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state),
            bus.subscribe(channels.OBJECT_POSES, lcmt_object_poses, self._on_objects),
        ]

    def _on_supervisor(self, msg: Any) -> None:
        with self._lock:
            self._follower.on_supervisor_state(msg)

    def _on_state(self, msg: Any) -> None:
        with self._lock:
            self.monitor.on_state(msg)

    def _on_objects(self, msg: Any) -> None:
        with self._lock:
            residual = self.monitor.on_object_poses(msg)
        if residual is None:
            return
        self.events.append((int(msg.utime), residual))
        self.bus.publish(
            channels.SUPERVISOR_EVENT,
            event_message(
                msg.utime, "left_manifold", SOURCE, residual.describe(), residual.position
            ),
        )
