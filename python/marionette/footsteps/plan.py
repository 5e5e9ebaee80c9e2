"""Footstep plans as the controller consumes them (lcmt_footstep_plan), and their timing.

A plan lists the steps after the initial stance: step i (0-based ``index``) moves one foot to a
sole pose (x, y, z, yaw) in world. The C++ footstep manager applies a plan from
``first_step_index`` on and never changes a step that has started (Dang §2.6.3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from marionette.footsteps.errors import InvalidProblem


@dataclass(frozen=True)
class StepTiming:
    """Durations of every step [s] and swing apex [m] (defaults suited to a 1.7 m humanoid)."""

    single_support: float = 0.8
    double_support: float = 0.2
    first_double_support: float = 0.8  # shift the CoM over the stance foot before step 0
    step_height: float = 0.05

    def __post_init__(self) -> None:
        if not (
            self.single_support > 0.0
            and self.double_support >= 0.0
            and self.first_double_support >= 0.0
            and self.step_height > 0.0
        ):
            raise InvalidProblem(f"invalid step timing {self}")


@dataclass
class Footstep:
    """One step: foot ``is_left`` lands at (x, y, z, yaw); optional swing passage points."""

    index: int
    is_left: bool
    pose: np.ndarray  # (4,) x, y, z [m], yaw [rad]
    duration: float
    double_support: float
    step_height: float
    via: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (n, 3) world [m]


@dataclass
class FootstepPlan:
    """Initial stance + steps. ``stance`` rows: left, right (x, y, z, yaw)."""

    stance: dict[str, np.ndarray]
    steps: list[Footstep]
    stop_at_end: bool = True

    @staticmethod
    def from_footprints(
        footprints: np.ndarray, is_left: np.ndarray, floor_z: float, timing: StepTiming
    ) -> FootstepPlan:
        """From the augmented robot's footprints -1..k ((k + 2, 3)) and their sides."""

        def pose(row):
            return np.array([row[0], row[1], floor_z, row[2]])

        stance = {
            ("left" if is_left[0] else "right"): pose(footprints[0]),
            ("left" if is_left[1] else "right"): pose(footprints[1]),
        }
        steps = []
        for i in range(2, footprints.shape[0]):
            steps.append(
                Footstep(
                    index=i - 2,
                    is_left=bool(is_left[i]),
                    pose=pose(footprints[i]),
                    duration=timing.single_support,
                    double_support=timing.first_double_support if i == 2 else timing.double_support,
                    step_height=timing.step_height,
                )
            )
        return FootstepPlan(stance, steps)

    def footprints(self) -> np.ndarray:
        """(n, 4) landing poses of the steps."""
        return np.array([s.pose for s in self.steps]).reshape(-1, 4)

    def to_lcm(self, utime: int, plan_id: int, first_step_index: int = 0):
        """lcmt_footstep_plan with the steps from ``first_step_index`` on."""
        from marionette import lcmt_footstep, lcmt_footstep_plan

        msg = lcmt_footstep_plan()
        msg.utime = int(utime)
        msg.plan_id = int(plan_id)
        msg.first_step_index = int(first_step_index)
        msg.stop_at_end = bool(self.stop_at_end)
        msg.steps = []
        for step in self.steps[first_step_index:]:
            s = lcmt_footstep()
            s.utime = 0
            s.index = step.index
            s.is_left = step.is_left
            s.x, s.y, s.z, s.yaw = (float(v) for v in step.pose)
            s.duration = step.duration
            s.double_support = step.double_support
            s.step_height = step.step_height
            s.num_via = int(step.via.shape[0])
            s.via = [list(map(float, v)) for v in step.via]
            msg.steps.append(s)
        msg.num_steps = len(msg.steps)
        return msg
