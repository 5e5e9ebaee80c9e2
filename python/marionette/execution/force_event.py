"""Force-threshold events from the robot state stream (thesis 000 §3.2.5.2: the FSM reacts to
"events (force, end of reference)"; §3.2.4.3: the gripper force is estimated from its motor
current, eq. 3.11-3.13).

:class:`ForceEventDetector` reads one joint's actuator effort in each ROBOT_STATE
(``joint_effort``: the simulator's actuator force, the motor current's stand-in), turns it into a
force f = s k τ / d (eq. 3.11-3.13: s the closing direction, k = k_τ k_gear, d the lever arm),
low-passes it at ``cutoff_frequency`` with the exact first-order discretisation for the actual
period between two states (y += α (f - y), α = 1 - exp(-2π f_c Δt)), and fires once when y
crosses ``threshold``. :class:`ForceEventNode` publishes it as ``force_threshold`` on
SUPERVISOR_EVENT, stamped with the controller time of the state that crossed: the supervisor
then ends the current reference early (``decisions.DecisionMachine.on_event``).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Any

from marionette import _core, channels, lcmt_robot_state
from marionette.execution.decisions import event_message
from marionette.lcm_bus import LcmBus

SOURCE = "force_monitor"
# The controller's defaults of eq. 3.11-3.13's constants (GripperAdmittanceOptions,
# cpp/include/marionette/sot/feature_gripper_admittance.h), which a task's parameters override.
_DEFAULTS = _core.gripper_admittance_defaults()
DEFAULT_LEVER_ARM: float = _DEFAULTS["lever_arm"]  # d [m]
DEFAULT_TORQUE_PER_EFFORT: float = _DEFAULTS["torque_per_effort"]  # k_τ k_gear


def force_estimate(
    effort: float, closing_direction: float, torque_per_effort: float, lever_arm: float
) -> float:
    """f = s k τ / d [N] of eq. 3.11-3.13 from a gripper joint's actuator effort τ
    (> 0 squeezes)."""
    return closing_direction * torque_per_effort * effort / lever_arm


@dataclass
class ForceEventDetector:
    joint: str
    threshold: float  # [N]
    closing_direction: float = -1.0  # s (TALOS grippers close towards negative angles)
    lever_arm: float = DEFAULT_LEVER_ARM
    torque_per_effort: float = DEFAULT_TORQUE_PER_EFFORT
    cutoff_frequency: float = 5.0  # [Hz]

    def __post_init__(self) -> None:
        if not self.joint:
            raise ValueError("ForceEventDetector needs a joint name")
        if not (self.threshold > 0 and self.lever_arm > 0 and self.cutoff_frequency > 0):
            raise ValueError(
                f"ForceEventDetector: threshold, lever_arm and cutoff_frequency must be > 0 "
                f"(got {self.threshold}, {self.lever_arm}, {self.cutoff_frequency})"
            )
        if self.closing_direction not in (-1.0, 1.0):
            raise ValueError(
                "ForceEventDetector: closing_direction must be +1 or -1, got "
                f"{self.closing_direction}"
            )
        self.filtered: float | None = None
        self._last_utime: int | None = None
        self.fired_utime: int | None = None

    def force(self, state: Any) -> float:
        """f of eq. 3.11-3.13 from the state's effort of ``joint`` [N]."""
        try:
            i = list(state.joint_name).index(self.joint)
        except ValueError:
            raise KeyError(
                f"ForceEventDetector: joint {self.joint!r} not in the robot state"
            ) from None
        return force_estimate(
            state.joint_effort[i], self.closing_direction, self.torque_per_effort, self.lever_arm
        )

    def feed(self, state: Any) -> float | None:
        """Updates the filter with one state; returns the filtered force when it first crosses the
        threshold (once), else None."""
        f = self.force(state)
        utime = int(state.utime)
        if self.filtered is None or self._last_utime is None or utime <= self._last_utime:
            self.filtered = f if self.filtered is None else self.filtered
        else:
            alpha = 1.0 - math.exp(
                -2.0 * math.pi * self.cutoff_frequency * (utime - self._last_utime) * 1e-6
            )
            self.filtered += alpha * (f - self.filtered)
        self._last_utime = utime
        if self.fired_utime is None and self.filtered > self.threshold:
            self.fired_utime = utime
            return self.filtered
        return None

    def rearm(self) -> None:
        """Fire again on the next crossing (e.g. the next closing step)."""
        self.fired_utime = None


class ForceEventNode:
    """Runs a :class:`ForceEventDetector` on ROBOT_STATE and publishes ``force_threshold``."""

    def __init__(self, bus: LcmBus, detector: ForceEventDetector) -> None:
        self.bus = bus
        self.detector = detector
        self.events: list[tuple[int, float]] = []
        self._lock = threading.Lock()
        self._subscription = bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)

    def _on_state(self, msg: Any) -> None:
        with self._lock:
            value = self.detector.feed(msg)
        if value is None:
            return
        self.events.append((int(msg.utime), value))
        detail = f"{self.detector.joint}: {value:.2f} N > {self.detector.threshold:.2f} N"
        self.bus.publish(
            channels.SUPERVISOR_EVENT,
            event_message(msg.utime, "force_threshold", SOURCE, detail, value),
        )
