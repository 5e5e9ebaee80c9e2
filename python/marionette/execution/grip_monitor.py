"""Grasps that hold nothing, seen from the robot's own senses (thesis 000 §3.4.4.1, failures'
detection): a gripper whose fingers reach their closed position holds nothing between them.

While a step holds a grasp (``Step.grasps``), the gripper's admittance closes the fingers until
they squeeze the handle at 5 N, then keeps squeezing (``gripper_admittance``): with the handle
between them they stop where it is; with nothing there — the object was missed, or slipped out —
they travel on to the closed position of robot.yaml (the fingers meeting). The encoder says so
before any camera does, and without one. :class:`GripMonitor` reads the gripper joints of each
ROBOT_STATE and reports a gripper whose fingers stay within ``empty_margin`` of the stroke from
the closed position for ``min_duration_s`` of controller time (two states at least, whatever
the state rate: an unpaced controller publishes a few per second); :class:`GripMonitorNode`
publishes it as ``grasp_lost`` on SUPERVISOR_EVENT (source ``grip_monitor``), the supervisor
fails the step and holds the robot (``decisions.FAILURES``): the arm does not carry on with an
empty hand.

The grippers watched are the factory's admittance grippers (``FactoryContext.gripper_joints``:
a joint, both positions), each only while the step holds it (a gripper that opens, or has not
yet closed, is not a failure).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

from marionette import channels, lcmt_robot_state, lcmt_supervisor_state
from marionette.execution.decisions import event_message
from marionette.execution.factory import GripperJoint
from marionette.execution.plan_steps import Step
from marionette.execution.step_follower import StepFollower
from marionette.lcm_bus import LcmBus

SOURCE = "grip_monitor"
EVENT = "grasp_lost"


@dataclass
class GripMonitorOptions:
    empty_margin: float = 0.1  # fraction of the stroke: closer to closed than this is empty
    min_duration_s: float = 0.05  # [s] that long in a row: one encoder glitch is not a loss


@dataclass(frozen=True)
class GraspLost:
    gripper: str
    handle: str
    position: float  # the finger joint [m or rad]
    closed_position: float

    def describe(self) -> str:
        return (
            f"{self.gripper} holds nothing: its fingers closed to {self.position:.4g} "
            f"(closed: {self.closed_position:.4g}); {self.handle} is not between them"
        )


@dataclass
class GripMonitor:
    """The check of the module docstring. Feed it :meth:`begin_step` and :meth:`on_state`; the
    latter returns the first loss of the step (once per step), else None."""

    grippers: dict[str, GripperJoint]  # the factory's, by gripper name
    options: GripMonitorOptions = field(default_factory=GripMonitorOptions)

    def __post_init__(self) -> None:
        self.step: Step | None = None
        self._since: dict[str, int] = {}  # gripper -> utime its fingers first read empty
        self._fired = False

    def begin_step(self, step: Step | None) -> None:
        """A new FSM state: grasps still held keep their timers."""
        held = set(step.grasps) if step is not None else set()
        self._since = {g: u for g, u in self._since.items() if g in held}
        self.step = step
        self._fired = False

    def on_state(self, state: Any) -> GraspLost | None:
        if self.step is None or self._fired:
            return None
        positions = dict(zip(state.joint_name, state.joint_position))
        for name, handle in sorted(self.step.grasps.items()):
            g = self.grippers.get(name)
            if g is None or g.joint not in positions:
                continue
            q = positions[g.joint]
            if g.closure(q) < 1.0 - self.options.empty_margin:
                self._since.pop(name, None)
                continue
            since = self._since.setdefault(name, state.utime)
            if state.utime - since >= round(self.options.min_duration_s * 1e6):
                self._fired = True
                return GraspLost(name, handle, q, g.closed_position)
        return None


class GripMonitorNode:
    """Runs a :class:`GripMonitor` on ``bus``: the step from SUPERVISOR_STATE (index into
    ``steps``), the finger joints from ROBOT_STATE; publishes ``grasp_lost``."""

    def __init__(self, bus: LcmBus, monitor: GripMonitor, steps: list[Step]) -> None:
        self.bus = bus
        self.monitor = monitor
        self.events: list[tuple[int, GraspLost]] = []
        self._lock = threading.Lock()
        self._follower = StepFollower(steps, monitor.begin_step)
        bus.subscribe(channels.SUPERVISOR_STATE, lcmt_supervisor_state, self._on_supervisor)
        bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)

    def _on_supervisor(self, msg: Any) -> None:
        with self._lock:
            self._follower.on_supervisor_state(msg)

    def _on_state(self, msg: Any) -> None:
        with self._lock:
            lost = self.monitor.on_state(msg)
        if lost is None:
            return
        self.events.append((int(msg.utime), lost))
        self.bus.publish(
            channels.SUPERVISOR_EVENT,
            event_message(msg.utime, EVENT, SOURCE, lost.describe(), lost.position),
        )
