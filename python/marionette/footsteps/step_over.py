"""Stepping over a bar (Dang ch. 5): footsteps alone, the upper body transparent (§3.3).

Initial sequence (§5.2.1): plan to the goal ignoring the bar; remove the footprints that touch
the bar region (one more when an odd number was removed, to keep left and right alternating);
re-optimise with the bar as an obstacle region, the crossing step allowed a longer stride, and
Algorithm 1 adding steps if the goal is no longer reached.

Online deformation (§5.3, Algorithm 3): the footprint landing just before the bar and the one
landing just after it ("the two subsequent steps that cross the bar") are kept fixed relative to
the bar: when the bar moves to X_WB', their targets become X_WB' · X_BF (a rigid motion; the
thesis's x ← x0 + y − y0 is its translation-only form), except along the bar's own axis (a bar
sliding along itself would drag them sideways), and the plan is re-optimised with the steps
already taken frozen. A bar moved away farther than the free steps before it can stretch
leaves the crossing footprints short of their targets: the free steps are then planned again as
an initial sequence from the stance the taken steps leave (:meth:`StepOverPlanner._fresh_sequence`;
when §5.2.1's removal leaves too few steps before the bar, for the bar a little farther, deformed
back onto it by Algorithm 3).

Priorities: step limits (bounds) > non-overlap > obstacles (bar + others) > crossing footprints
> goal stance > step preference.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from marionette.footsteps.augmented_robot import (
    AugmentedConfiguration,
    AugmentedRobot,
    Stance,
    planar_compose,
    planar_relative,
)
from marionette.footsteps.constraints import (
    FINAL_STANCE,
    Constraint,
    FootNonOverlap,
    FootprintPoseTask,
    ObstacleAvoidance,
    StanceGoalTask,
    StepBounds,
    StepLimits,
    StepPreferenceTask,
    Task,
    sole_clearance,
)
from marionette.footsteps.errors import InvalidProblem, PlanningFailed
from marionette.footsteps.obstacles import Bar, Obstacle
from marionette.footsteps.optimizer import FootstepOptimizer, OptimizerSettings, SolveReport
from marionette.footsteps.plan import FootstepPlan, StepTiming
from marionette.footsteps.planner import default_first_side
from marionette.footsteps.robot_model import FootShape
from marionette.footsteps.swing import crossing_via_points


@dataclass
class StepOverOptions:
    non_overlap_margin: float = 0.02
    nominal_width: float = 0.17
    # Longest step allowed over the bar: the straddling double support needs the sole length
    # + the bar's width + two buffers between the sole centres.
    crossing_max_length: float | None = None  # None: computed from the bar (+ 2 cm)
    crossing_duration: float = 1.2  # single support of the crossing steps [s]
    swing_margin: float = 0.03  # eq. 5.1 clearance of the swing [m]
    # Replans (Algorithm 3): the crossing footprints are tasks above the goal, and once the
    # crossing stride is at its bound a moved bar leaves them short by a fraction of a
    # millimetre; with the default 10 µm the Gauss–Newton loop ran its 300 iterations (5 s).
    # 0.1 mm is well inside the bar's 3 cm buffer; the iteration cap bounds a replan's time.
    replan_constraint_tolerance: float = 1e-4  # [m]
    replan_max_iterations: int = 60
    # A bar moved away by more than the free steps before it can stretch leaves the crossing
    # footprints short of their targets (the optimizer twists the feet to gain reach): the free
    # steps are then planned again as an initial sequence (§5.2.1) from the steps taken.
    crossing_tolerance: float = 0.01  # [m] crossing footprint to its target
    fresh_shifts: tuple[float, ...] = (0.0, 0.06, 0.12)  # [m] (see _fresh_sequence)
    # Algorithm 3 deforms the plan for small moves; once the bar has moved this far across
    # itself since the crossing was planned, the free steps are planned afresh instead (a plan
    # made for a bar 10-20 cm farther keeps its step count and ends in short shuffling steps,
    # measured: falls at the goal).
    fresh_after_move: float = 0.05  # [m]
    fresh_max_iterations: int = 15  # per solve with the bar

    def with_crossing_duration(self, seconds: float | None) -> StepOverOptions:
        """These options with the crossing swings' single support ``seconds`` (None: kept)."""
        if seconds is None:
            return self
        if not (np.isfinite(seconds) and seconds > 0.0):
            raise InvalidProblem(f"crossing duration must be > 0 s, got {seconds}")
        return dataclasses.replace(self, crossing_duration=float(seconds))


class StepOverPlanner:
    """Footsteps from ``stance`` to the ``goal`` stance (x, y, yaw) over ``bar`` (see module)."""

    def __init__(
        self,
        stance: Stance,
        goal,
        bar: Bar,
        foot: FootShape,
        obstacles: list[Obstacle] | None = None,
        first_side: str | None = None,
        limits: StepLimits | None = None,
        options: StepOverOptions | None = None,
        settings: OptimizerSettings | None = None,
        timing: StepTiming | None = None,
    ) -> None:
        self.goal = StanceGoalTask(goal)
        self.bar = bar
        self.foot = foot
        self.obstacles = list(obstacles or [])
        self.options = options or StepOverOptions()
        self.limits = limits or StepLimits(final=FINAL_STANCE)
        self.settings = settings or OptimizerSettings()
        self.timing = timing or StepTiming()
        side = first_side or default_first_side(stance, np.asarray(goal, dtype=float)[:2])
        self.augmented = AugmentedRobot(None, stance, side, foot)
        self.config = self.augmented.neutral_configuration(0)
        self.frozen_steps = 0
        self.crossing: tuple[int, int] | None = None  # footprint indices (before, after)
        self._crossing_in_bar: tuple[np.ndarray, np.ndarray] | None = None
        self._crossing_bar_center = np.zeros(2)  # the bar when they were recorded
        self.last_report: SolveReport | None = None

    # -- geometry ------------------------------------------------------------------------
    def side_of_bar(self, footprints: np.ndarray) -> np.ndarray:
        """+1 for footprints on the start side of the bar, −1 past it: (m,)."""
        n = self.bar.normal()
        start = 0.5 * (self.augmented.stance.left[:2] + self.augmented.stance.right[:2])
        sign0 = np.sign(n @ (start - self.bar.center)) or 1.0
        return np.where(sign0 * ((footprints[:, :2] - self.bar.center) @ n) > 0.0, 1.0, -1.0)

    def touching_bar(self, footprints: np.ndarray) -> np.ndarray:
        """Footprints whose sole comes within the bar's buffer: (m,) bool."""
        return np.array(
            [np.min(sole_clearance(pose, self.foot, self.bar)[0]) < 0.0 for pose in footprints],
            dtype=bool,
        )

    def crossing_bounds(self) -> StepBounds:
        d = self.limits.default
        needed = self.foot.length + 2.0 * self.bar.radius + 2.0 * self.bar.buffer
        longest = self.options.crossing_max_length or max(d.max_length, needed + 0.02)
        return StepBounds(
            d.min_length, longest, d.min_width, d.max_width, d.max_outward_yaw, d.max_inward_yaw
        )

    # -- planning ------------------------------------------------------------------------
    def plan(self) -> SolveReport:
        """Initial sequence over the bar (§5.2.1), see :meth:`_fresh_sequence`."""
        self.frozen_steps = 0
        return self._fresh_sequence()

    def _initial_sequence(self, bar_iterations: int | None = None) -> SolveReport:
        """§5.2.1 from the stance: to the goal ignoring the bar, the footprints on the bar
        removed, re-optimised with the bar (at most ``bar_iterations`` per solve)."""
        self.frozen_steps = 0
        self.crossing = None
        self._crossing_in_bar = None
        # 1. To the goal, ignoring the bar.
        self.config = self.augmented.neutral_configuration(0)
        report = self._solve(with_bar=False)
        if not report.converged:
            raise PlanningFailed(f"goal not reached even without the bar: {report}")
        # 2. Remove the footprints on the bar (and one more if their number is odd).
        fp = self.augmented.footprints(self.config.steps)[2:]  # P_1..P_k
        touching = np.flatnonzero(self.touching_bar(fp))
        keep = np.ones(fp.shape[0], dtype=bool)
        if touching.size:
            keep[touching] = False
            if touching.size % 2 == 1:
                extra = touching[-1] + 1 if touching[-1] + 1 < fp.shape[0] else touching[0] - 1
                keep[extra] = False
        self.config = self._chain_through(fp[keep])
        # 3. Re-optimise with the bar, the crossing step allowed to be long.
        settings = (
            self.settings
            if bar_iterations is None
            else dataclasses.replace(self.settings, max_iterations=bar_iterations)
        )
        self._set_crossing_limits()
        report = self._solve(with_bar=True, settings=settings)
        if bar_iterations is not None and not report.converged:
            return report  # stalled: the caller tries another way
        self._set_crossing_limits()
        report = self._solve(with_bar=True, settings=settings)
        self._record_crossing()
        return report

    def update_bar(self, bar: Bar, executed_steps: int | None = None) -> SolveReport:
        """Algorithm 3: the bar moved; keep the crossing footprints fixed relative to it."""
        if self.crossing is None or self._crossing_in_bar is None:
            raise InvalidProblem("plan() first: there is no crossing to keep")
        if executed_steps is not None:
            self.frozen_steps = executed_steps
        self.bar = bar
        held = (
            self.config,
            self.crossing,
            self._crossing_in_bar,
            self._crossing_bar_center,
            dict(self.limits.overrides),
        )
        moved = abs(float(self.bar.normal() @ (self.bar.center - self._crossing_bar_center)))
        if moved > self.options.fresh_after_move and self.crossing[0] > self.frozen_steps:
            try:
                return self._fresh_sequence()
            except PlanningFailed:
                pass  # Algorithm 3 below
        report = self._deform()
        if self._crossing_short():
            try:
                report = self._fresh_sequence()
            except PlanningFailed:
                # Keep the previous plan (the caller sees a report that did not converge).
                (
                    self.config,
                    self.crossing,
                    self._crossing_in_bar,
                    self._crossing_bar_center,
                    self.limits.overrides,
                ) = held
        return report

    def _deform(self) -> SolveReport:
        """Algorithm 3's solve on the current bar. A short first pass tells a bar beyond the
        strides' reach (its crossing stays short) before the full iteration budget is spent."""
        settings = dataclasses.replace(
            self.settings,
            constraint_tolerance=self.options.replan_constraint_tolerance,
            max_iterations=self.options.replan_max_iterations,
        )
        first = min(self.options.fresh_max_iterations, settings.max_iterations)
        report = self._solve(
            with_bar=True,
            crossing_targets=True,
            settings=dataclasses.replace(settings, max_iterations=first),
        )
        if not report.converged and not self._crossing_short():
            report = self._solve(
                with_bar=True,
                crossing_targets=True,
                settings=dataclasses.replace(
                    settings, max_iterations=settings.max_iterations - first
                ),
            )
        return report

    def _fresh_sequence(self) -> SolveReport:
        """The free steps planned again as an initial sequence (§5.2.1) from the stance the
        steps already taken leave (P_(f-1), P_f), spliced after them; the new crossing is the one
        Algorithm 3 then keeps on the bar. The removal of §5.2.1 can leave too few steps before
        a bar just out of the strides' reach (the solve then stalls): the sequence is then
        planned for the bar ``fresh_shifts`` farther and deformed back onto it by Algorithm 3."""
        f = self.frozen_steps
        fp = self.augmented.footprints(self.config.steps)  # rows: P_-1..P_k
        mover = self.augmented.side_of(f + 1)
        feet = {mover: fp[f], self.augmented.side_of(f): fp[f + 1]}  # P_(f-1), P_f
        stance = Stance(feet["left"], feet["right"], self.augmented.stance.floor_z)
        away = self._away_from(0.5 * (stance.left[:2] + stance.right[:2]))
        for shift in self.options.fresh_shifts:
            fresh = StepOverPlanner(
                stance,
                self.goal.target,
                self.bar.moved_to(self.bar.center + shift * away, self.bar.yaw),
                self.foot,
                self.obstacles,
                first_side=mover,
                limits=dataclasses.replace(self.limits, overrides={}),
                options=self.options,
                settings=self.settings,
                timing=self.timing,
            )
            try:
                report = fresh._initial_sequence(self.options.fresh_max_iterations)
            except PlanningFailed:
                continue
            if not report.converged or fresh.crossing is None:
                continue
            if shift:
                fresh.bar = self.bar
                report = fresh._deform()
                if not report.converged or fresh._crossing_short():
                    continue
                # The crossing now stands on this bar (shifted across it, not along): the next
                # estimate of the same bar is a deformation, not another fresh sequence (it was:
                # every later estimate planned afresh, ~200 ms each).
                fresh._crossing_bar_center = self.bar.center.copy()
            self.config = AugmentedConfiguration(
                np.vstack([self.config.steps[:f], fresh.config.steps]), None
            )
            self.crossing = (fresh.crossing[0] + f, fresh.crossing[1] + f)
            self._crossing_in_bar = fresh._crossing_in_bar
            self._crossing_bar_center = fresh._crossing_bar_center
            self.limits.overrides = {i + f: b for i, b in fresh.limits.overrides.items()}
            return report
        raise PlanningFailed(
            f"no sequence over the bar from the stance after step {f} "
            f"(bar shifted by {list(self.options.fresh_shifts)} m)"
        )

    def crossing_errors(self) -> dict[int, np.ndarray]:
        """Footprint index -> (target − footprint) in x, y [m] of the crossing footprints still
        free (Algorithm 3's targets on the current bar)."""
        if self.crossing is None or self._crossing_in_bar is None:
            return {}
        fp = self.augmented.footprints(self.config.steps)
        return {
            i: target[:2] - fp[i + 1][:2]
            for i, target in self._crossing_targets().items()
            if i > self.frozen_steps
        }

    def _crossing_targets(self) -> dict[int, np.ndarray]:
        """Algorithm 3's targets of the crossing footprints on the current bar: fixed relative
        to it across it and in yaw, not along its axis — a bar sliding along its own axis
        leaves them where they were along it (fixed to it, they would be dragged sideways,
        measured: sideways steps and falls)."""
        if self.crossing is None or self._crossing_in_bar is None:
            return {}
        axis = np.array([np.cos(self.bar.yaw), np.sin(self.bar.yaw)])
        slide = float(axis @ (self.bar.center - self._crossing_bar_center))
        return {
            i: planar_compose(self.bar.pose(), rel - np.array([slide, 0.0, 0.0]))
            for i, rel in zip(self.crossing, self._crossing_in_bar)
        }

    def _crossing_square_tasks(self) -> list[Task]:
        """The footprints of the two swings over the bar (each foot's last before it and first
        past it) square to the bar: yaw along its normal, towards its far side. The straddling
        stance and the swings over the bar (eq. 5.1, in the plane across it) are designed for
        feet across the bar; without it a bar turned by 7.8° was crossed with the feet 15°
        oblique to it (twisted the other way for reach) and TALOS fell on the second crossing
        swing. Algorithm 3's targets (the two straddling footprints) follow the bar in yaw from
        this crossing, these tasks keep the two others square too."""
        assert self.crossing is not None
        stance = self.augmented.stance
        away = self._away_from(0.5 * (stance.left[:2] + stance.right[:2]))
        yaw = float(np.arctan2(away[1], away[0]))
        before, past = self.crossing
        last = self.augmented.footprints(self.config.steps).shape[0] - 2  # k
        return [
            FootprintPoseTask(i, (0.0, 0.0, yaw), weights=(0.0, 0.0, 1.0), name=f"square_{i}")
            for i in (before - 1, before, past, past + 1)
            if self.frozen_steps < i <= last
        ]

    def _away_from(self, start: np.ndarray) -> np.ndarray:
        """The bar's floor normal pointing from ``start`` (x, y) towards its far side."""
        n = self.bar.normal()
        return n * (np.sign(n @ (self.bar.center - start)) or 1.0)

    def _crossing_short(self) -> bool:
        """A free crossing footprint lies more than ``crossing_tolerance`` short of its target,
        towards the bar's far side: the steps before it cannot stretch that far."""
        away = self._away_from(
            0.5 * (self.augmented.stance.left[:2] + self.augmented.stance.right[:2])
        )
        return any(
            np.linalg.norm(e) > self.options.crossing_tolerance and e @ away > 0.0
            for e in self.crossing_errors().values()
        )

    def set_goal(self, goal) -> None:
        self.goal.set_target(goal)

    def _chain_through(self, footprints: np.ndarray) -> AugmentedConfiguration:
        """Step variables through given world footprints P_1..P_m (after P_-1, P_0)."""
        poses = np.vstack([self.augmented.root[None], footprints])
        steps = np.array(
            [planar_relative(poses[i], poses[i + 1]) for i in range(footprints.shape[0])]
        ).reshape(-1, 3)
        return AugmentedConfiguration(steps, None)

    def _set_crossing_limits(self) -> None:
        """The step landing first past the bar may be long (the others keep the default)."""
        fp = self.augmented.footprints(self.config.steps)
        side = self.side_of_bar(fp)  # rows -1..k
        past = np.flatnonzero(side < 0.0)
        self.limits.overrides = {}
        if past.size:
            first_past = int(past[0]) - 1  # footprint index
            self.limits.overrides[first_past] = self.crossing_bounds()
            self.crossing = (first_past - 1, first_past)

    def _record_crossing(self) -> None:
        if self.crossing is None:
            return
        fp = self.augmented.footprints(self.config.steps)
        bar_pose = self.bar.pose()
        before, after = self.crossing
        self._crossing_in_bar = (
            planar_relative(bar_pose, fp[before + 1]),
            planar_relative(bar_pose, fp[after + 1]),
        )
        self._crossing_bar_center = self.bar.center.copy()

    def _levels(self, with_bar: bool, crossing_targets: bool) -> list[Constraint | Task]:
        first = self.frozen_steps + 1
        levels: list[Constraint | Task] = [
            FootNonOverlap(self.options.non_overlap_margin, first_step=first)
        ]
        obstacles = self.obstacles + ([self.bar] if with_bar else [])
        if obstacles:
            levels.append(ObstacleAvoidance(obstacles, first_step=first))
        if with_bar and self.crossing is not None:
            levels.extend(self._crossing_square_tasks())
        if crossing_targets and self.crossing is not None:
            for index, target in self._crossing_targets().items():
                if index > self.frozen_steps:  # a landed footprint cannot be moved
                    levels.append(
                        FootprintPoseTask(
                            index, target, weights=(1.0, 1.0, 1.0), name=f"crossing_{index}"
                        )
                    )
        levels.append(self.goal)
        levels.append(StepPreferenceTask(self.options.nominal_width, first))
        return levels

    def _solve(
        self,
        with_bar: bool,
        crossing_targets: bool = False,
        settings: OptimizerSettings | None = None,
    ) -> SolveReport:
        optimizer = FootstepOptimizer(
            self.augmented,
            self._levels(with_bar, crossing_targets),
            self.goal,
            self.limits,
            settings or self.settings,
        )
        self.config, report = optimizer.solve(self.config, self.frozen_steps)
        self.last_report = report
        return report

    # -- output --------------------------------------------------------------------------
    def result(self) -> FootstepPlan:
        """The plan, the two bar-crossing swings with passage points (eq. 5.1)."""
        kin = self.augmented.evaluate(self.config)
        plan = FootstepPlan.from_footprints(
            kin.footprints, kin.is_left, self.augmented.stance.floor_z, self.timing
        )
        side = self.side_of_bar(kin.footprints)
        z = self.augmented.stance.floor_z
        for step in plan.steps:
            i = step.index + 1  # footprint index of landing
            lift = kin.footprints[i - 2 + 1]  # P_(i-2)
            if side[i + 1] != side[i - 1]:  # lands past, lifted before
                via, apex = crossing_via_points(
                    np.array([lift[0], lift[1], z, lift[2]]),
                    step.pose,
                    self.bar,
                    self.foot.length,
                    self.foot.width,
                    self.options.swing_margin,
                )
                step.via = via
                step.step_height = apex
                step.duration = self.options.crossing_duration
        return plan
