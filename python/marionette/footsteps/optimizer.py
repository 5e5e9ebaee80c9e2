"""Gauss–Newton over the prioritised hierarchy, with Algorithm 1's automatic number of steps.

One iteration linearises every level (constraints g ≥ 0 and tasks e = 0, in priority order) at
the current augmented configuration, solves the hierarchy (:mod:`.hierarchy`) for the tangent
step dv within the step/joint limits and a trust region, and integrates. It stops at a fixed
point (|dv|∞ small). When the primary task (hand, or goal footprint) stalls above its
tolerance, a virtual link is added at the end of the chain (Dang Algorithm 1).

Frozen variables (Dang Algorithm 2 line 11, §6.2.2):
* the first ``frozen_steps`` steps (already executed or in progress) never change;
* ``posture_frozen``: the robot's configuration is fixed, so only footstep dofs move; the last
  step Δ_k is then fixed too, since it is the relative pose of the two soles of that posture.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from marionette.footsteps.augmented_robot import AugmentedConfiguration, AugmentedRobot
from marionette.footsteps.constraints import Constraint, StepLimits, Task, joint_limits
from marionette.footsteps.errors import InvalidProblem
from marionette.footsteps.hierarchy import HierarchySettings, Level, solve_hierarchy


@dataclass
class OptimizerSettings:
    max_iterations: int = 300
    max_steps: int = 40
    step_tolerance: float = 1e-6  # fixed point: |dv|∞ below this
    settle_ratio: float = 1e-3  # lower tasks settled: each squared error improves by
    settle_absolute: float = 1e-8  # less than ratio × itself + absolute
    constraint_tolerance: float = 1e-5  # levels above the primary: residual below this
    task_tolerance: float = 1e-3  # primary task reached when ||e|| ≤ this [m]
    trust_region_steps: float = 0.1  # |ΔΔx|, |ΔΔy| [m] per iteration
    trust_region_yaw: float = 0.05  # |ΔΔθ| [rad] per iteration (the chain's lever arm)
    yaw_scale: float = 0.25  # [rad/m] metric of the step yaws (see solve)
    trust_region_robot: float = 0.1  # |dv| per iteration on the robot [rad, m]
    blocked_ratio: float = 0.9  # Algorithm 1: primary blocked if its linearised level
    # keeps this fraction of its (clamped) error
    blocked_iterations: int = 2  # this many iterations in a row,
    stall_window: int = 5  # or stalled if over this many iterations
    stall_ratio: float = 0.05  # its error dropped by less than this fraction
    stall_min_error: float = 0.02  # while above this [m]
    stretched_fraction: float = 0.6  # ... or when this fraction of free steps is at max length
    stretched_tolerance: float = 0.005  # (within this) [m]
    auto_steps: bool = True  # Algorithm 1 on/off
    reach_check: bool = False  # add steps before iterating while the linearised primary
    # cannot be reached within the limits (see solve)
    reach_tolerance: float = 0.02  # ... by more than this [m] (see _extend_to_reach)
    relax_stretched: bool = True  # one more step when converged fully stretched (see solve)
    line_search_steps: int = 5  # step halvings at most (see _line_search)
    line_search_slack: float = 1e-4  # the levels above the primary may reach this meanwhile
    restore_primary: bool = False  # second-order correction of the primary task after
    # each step, on the free steps (see _restored)
    hierarchy: HierarchySettings = field(default_factory=HierarchySettings)


@dataclass
class SolveReport:
    converged: bool = False  # fixed point reached with the primary task satisfied
    iterations: int = 0
    qp_solves: int = 0
    steps_added: int = 0
    primary_error: float = np.inf
    time_s: float = 0.0
    pose_iterations: int = 0  # posture-frozen replanning: iterations of the stance solve
    level_residuals: dict[str, float] = field(default_factory=dict)


class FootstepOptimizer:
    """Prioritised optimisation of an augmented robot (see module doc).

    ``levels``: Constraint and Task objects, highest priority first. ``primary``: the task whose
    error decides Algorithm 1 (must be one of ``levels``).
    """

    def __init__(
        self,
        augmented: AugmentedRobot,
        levels: Sequence[Constraint | Task],
        primary: Task,
        limits: StepLimits | None = None,
        settings: OptimizerSettings | None = None,
        posture_limits: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        if primary not in levels:
            raise InvalidProblem("the primary task must be one of the levels")
        self.augmented = augmented
        self.levels = list(levels)
        self.primary = primary
        self.limits = limits or StepLimits()
        self.settings = settings or OptimizerSettings()
        # Joint position limits of the final posture (nq each), within the model's own.
        self.posture_limits = posture_limits

    # -- variables ---------------------------------------------------------------------------
    def free_indices(self, k: int, frozen_steps: int, posture_frozen: bool) -> np.ndarray:
        """Indices of the free tangent dofs in [steps (3k) | robot (nv) if posture free]."""
        last_free_step = k - 1 if (posture_frozen and self.augmented.robot is not None) else k
        steps = np.arange(3 * min(frozen_steps, k), 3 * max(last_free_step, 0))
        if posture_frozen or self.augmented.robot is None:
            return steps
        robot = self.augmented.robot
        nv = robot.model.nv
        robot_idx = np.setdiff1d(np.arange(nv), robot.frozen_velocity_indices())
        return np.concatenate([steps, 3 * k + robot_idx])

    def limit_gaps(
        self, config: AugmentedConfiguration, free: np.ndarray, robot_free: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """(limit − value) on the free dofs: lower (≤ 0 inside) and upper (≥ 0 inside)."""
        k = config.num_steps
        is_left = self.augmented.is_left(k)[2:]
        lo_s, hi_s = self.limits.bounds(is_left, with_final=True)
        steps = config.steps.reshape(-1)
        lo, hi = lo_s - steps, hi_s - steps
        if robot_free:
            lo_r, hi_r = joint_limits(
                self.augmented.require_robot().model,
                config.require_q_robot(),
                self.posture_limits,
            )
            lo, hi = np.concatenate([lo, lo_r]), np.concatenate([hi, hi_r])
        return lo[free], hi[free]

    def bounds(
        self, config: AugmentedConfiguration, free: np.ndarray, robot_free: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of dv on the free dofs: limits − current value, within the trust region."""
        s = self.settings
        lo, hi = self.limit_gaps(config, free, robot_free)
        k = config.num_steps
        tr = np.tile([s.trust_region_steps, s.trust_region_steps, s.trust_region_yaw], k)
        if robot_free:
            nv = self.augmented.require_robot().model.nv
            tr = np.concatenate([tr, np.full(nv, s.trust_region_robot)])
        tr = tr[free]
        # Clip to the trust region; clipping both keeps lower ≤ upper, and a dof outside its
        # limits is pulled back by at most the trust region per iteration.
        return np.clip(lo, -tr, tr), np.clip(hi, -tr, tr)

    # -- one iteration -----------------------------------------------------------------------
    @staticmethod
    def value(item: Constraint | Task, kin) -> np.ndarray:
        """g(q) of a constraint or e(q) of a task at ``kin``, computed once per kinematics."""
        cache = kin.__dict__.setdefault("_values", {})
        key = id(item)
        if key not in cache:
            cache[key] = (
                item.compute_value(kin) if isinstance(item, Constraint) else item.compute_error(kin)
            )
        return cache[key]

    def linearise(self, kin, free: np.ndarray, count: int | None = None) -> list[Level]:
        """One Level per constraint/task (in priority order), restricted to the free dofs;
        the first ``count`` levels only if given."""
        levels = []
        for item in self.levels[:count]:
            if isinstance(item, Constraint):
                value = self.value(item, kin)
                jacobian = (
                    item.compute_jacobian(kin)[:, free]
                    if value.shape[0]
                    else np.zeros((0, free.shape[0]))
                )
                levels.append(Level.constraint(item.name, jacobian, value))
            else:
                error = self.value(item, kin)
                norm = float(np.linalg.norm(error))
                if norm > item.max_step:
                    error = error * (item.max_step / norm)
                levels.append(
                    Level.task(
                        item.name,
                        item.compute_jacobian(kin)[:, free],
                        error,
                        best_effort=item.best_effort,
                    )
                )
        return levels

    # -- the loop ----------------------------------------------------------------------------
    def solve(
        self, config: AugmentedConfiguration, frozen_steps: int = 0, posture_frozen: bool = False
    ) -> tuple[AugmentedConfiguration, SolveReport]:
        """Optimise from ``config`` (warm start); returns the new configuration and a report.

        Converged: the primary task within ``task_tolerance``, the levels above it satisfied,
        and the levels below it settled (step below ``step_tolerance`` or their squared error
        improving by less than ``settle_ratio`` per iteration).
        """
        s = self.settings
        report = SolveReport()
        start = time.perf_counter()
        robot_free = not posture_frozen and self.augmented.robot is not None
        if posture_frozen and self.augmented.robot is not None and config.num_steps < 1:
            raise InvalidProblem("posture_frozen needs at least one step (the last one is fixed)")
        primary_index = self.levels.index(self.primary)
        self._frozen = (frozen_steps, posture_frozen)
        kin = self.augmented.evaluate(config, robot_free=robot_free)
        error, above, below = self._merits(kin)
        history = [error]
        blocked_count = 0
        reach_check = s.reach_check and s.auto_steps  # at the first iteration only
        if reach_check and error > s.trust_region_steps:
            # Farther than a trust-region step: the first iteration would most likely leave the
            # primary short and call the reach check below, whose added steps would discard
            # that iteration. Check first (the same test, on the same configuration).
            reach_check = False
            k_before = config.num_steps
            config, kin = self._extend_to_reach(
                config, kin, frozen_steps, posture_frozen, robot_free, report
            )
            if config.num_steps != k_before:
                error, above, below = self._merits(kin)
                history = [error]
        for _ in range(s.max_iterations):
            k = config.num_steps
            free = self.free_indices(k, frozen_steps, posture_frozen)
            if free.shape[0] == 0:
                if error > s.task_tolerance and s.auto_steps and k < s.max_steps:
                    config, kin = self._add_step(config, robot_free, report)
                    error, above, below = self._merits(kin)
                    history = [error]
                    continue
                break
            levels = self.linearise(kin, free)
            lo, hi = self.bounds(config, free, robot_free)
            solution = self._solve_levels(levels, lo, hi, free, k)
            report.iterations += 1
            report.qp_solves += solution.qp_solves
            if reach_check and solution.levels[primary_index].residual > s.reach_tolerance:
                # The trust region keeps the primary out of reach this iteration: is it out of
                # reach of the chain's limits too?
                reach_check = False
                k_before = config.num_steps
                config, kin = self._extend_to_reach(
                    config, kin, frozen_steps, posture_frozen, robot_free, report
                )
                if config.num_steps != k_before:
                    error, above, below = self._merits(kin)
                    history = [error]
                    continue
            reach_check = False
            if self._predicted_settled(error, above, below, solution):
                # Already there: the linearised lower levels predict no useful improvement.
                if self._relaxing_step_wanted(k, config, free):
                    config, kin = self._add_step(config, robot_free, report)
                    error, above, below = self._merits(kin)
                    history = [error]
                    continue
                report.converged = True
                break
            # The step of the levels down to the primary task, and the lower levels' addition.
            x_high = solution.x_after[primary_index]
            dv_high = np.zeros(kin.nv)
            dv_high[free] = x_high
            dv_low = np.zeros(kin.nv)
            dv_low[free] = solution.x - x_high
            config, kin, alpha = self._line_search(
                config, kin, dv_high, dv_low, error, above, robot_free
            )
            step = float(np.max(np.abs(x_high + alpha * (solution.x - x_high))))
            previous_below = below
            error, above, below = self._merits(kin)
            history.append(error)
            reached = error <= s.task_tolerance and above <= s.constraint_tolerance
            settled = step < s.step_tolerance or bool(
                np.all(previous_below - below < s.settle_ratio * previous_below + s.settle_absolute)
            )
            if reached and settled:
                # Reached, but only with every step at full length: the tasks below are
                # strained (the robot twists to reach). One more step relaxes the chain.
                if self._relaxing_step_wanted(k, config, free):
                    config, kin = self._add_step(config, robot_free, report)
                    error, above, below = self._merits(kin)
                    history = [error]
                    continue
                report.converged = True
                break
            if reached or not s.auto_steps or k >= s.max_steps:
                continue
            if error <= s.task_tolerance:
                # The primary task is reached; only levels above it are not (e.g. step-over's
                # crossing footprints held on a moved bar beyond the free steps' reach).
                # Algorithm 1's steps, appended at the end of the chain, serve the primary task:
                # at a fixed point stop (not converged) instead of adding them up to max_steps.
                if step < s.step_tolerance:
                    break
                continue
            # Algorithm 1: at a local minimum of the primary task the chain is too short. The
            # hierarchy tells it directly: its linearised primary level cannot reduce the
            # (clamped) error, because the levels above and the limits block every direction.
            clamped = min(history[-2], self.primary.max_step)
            blocked = solution.levels[primary_index].residual > s.blocked_ratio * clamped
            blocked_count = blocked_count + 1 if blocked else 0
            slow = history[-2] - error < 0.25 * self.primary.max_step
            # ... or, far from the target, no real progress over a few iterations (the
            # linearisation promises progress that the nonlinear levels above take back).
            window = history[-1 - s.stall_window] if len(history) > s.stall_window else np.inf
            stalled = error > s.stall_min_error and window - error < s.stall_ratio * window
            if (
                blocked_count >= s.blocked_iterations
                or step < s.step_tolerance
                or stalled
                or (slow and error > s.stall_min_error and self._stretched(config, free))
            ):
                config, kin = self._add_step(config, robot_free, report)
                error, above, below = self._merits(kin)
                history = [error]
                blocked_count = 0
        report.primary_error = error
        report.level_residuals = self.residuals(kin)
        report.time_s = time.perf_counter() - start
        return config, report

    def _solve_levels(self, levels, lo: np.ndarray, hi: np.ndarray, free: np.ndarray, k: int):
        """solve_hierarchy in the metric of the step space: yaw variables are solved in units of
        yaw/yaw_scale, so the least-norm steps of each level do not favour turning (a yaw moves
        the far end of the chain by its lever arm) and plans do not zig-zag."""
        s = self.settings
        scale = np.where((free < 3 * k) & (free % 3 == 2), s.yaw_scale, 1.0)
        for level in levels:
            level.matrix = level.matrix * scale
        solution = solve_hierarchy(levels, lo / scale, hi / scale, s.hierarchy)
        solution.x = solution.x * scale
        solution.x_after = [x * scale for x in solution.x_after]
        return solution

    def _extend_to_reach(self, config, kin, frozen_steps, posture_frozen, robot_free, report):
        """Algorithm 1's step additions decided up front: while the levels down to the primary
        task, linearised with the full (unclamped) primary error and the step/joint limits alone
        (no trust region), leave more than ``reach_tolerance`` of it, the chain is too short and
        a step is added. For a footsteps-only chain the footprint positions are linear in
        (Δx, Δy) at fixed yaws, so the test is exact but for the yaws' curvature (which only
        shortens the reach: a linearised yaw moves the far end along the tangent of its arc); the
        Gauss–Newton loop would otherwise spend iterations at the trust region before
        detecting the same block (its additions remain as the fallback). Called only when the
        first trust-region-bounded iteration leaves the primary task short."""
        s = self.settings
        primary_index = self.levels.index(self.primary)
        while config.num_steps < s.max_steps:
            k = config.num_steps
            free = self.free_indices(k, frozen_steps, posture_frozen)
            if free.shape[0] == 0:
                break
            levels = self.linearise(kin, free, primary_index + 1)
            levels[-1].vector = -self.value(self.primary, kin)
            lo, hi = self.limit_gaps(config, free, robot_free)
            solution = self._solve_levels(levels, lo, hi, free, k)
            if solution.levels[primary_index].residual <= s.reach_tolerance:
                break
            config, kin = self._add_step(config, robot_free, report)
        return config, kin

    def _predicted_settled(self, error: float, above: float, below: np.ndarray, solution) -> bool:
        """The primary task and the levels above it are satisfied, and for every (non
        regularisation) task below, the hierarchy's linearised residual improves its squared
        error by less than settle_ratio × itself + settle_absolute."""
        s = self.settings
        if error > s.task_tolerance or above > s.constraint_tolerance:
            return False
        start = self.levels.index(self.primary) + 1
        residuals = [
            solution.levels[i].residual ** 2
            for i, item in enumerate(self.levels[start:], start)
            if isinstance(item, Task) and not item.regularisation
        ]
        return bool(
            np.all(below - np.array(residuals) < s.settle_ratio * below + s.settle_absolute)
        )

    def _add_step(self, config, robot_free, report):
        """Algorithm 1's new virtual link. With a frozen posture, two in-place steps: the last
        step is the relative pose of the posture's two soles, and one added step would swap
        the feet under the robot (its inverse relation can leave the step bounds)."""
        count = 2 if (self.augmented.robot is not None and not robot_free) else 1
        for _ in range(count):
            config = self.augmented.add_step(config)
        report.steps_added += count
        return config, self.augmented.evaluate(config, robot_free=robot_free)

    def _merits(self, kin) -> tuple[float, float, np.ndarray]:
        """(||primary error||, residual above it, squared error of each task below it)."""
        error = float(np.linalg.norm(self.value(self.primary, kin)))
        below = [
            float(np.sum(self.value(item, kin) ** 2))
            for item in self.levels[self.levels.index(self.primary) + 1 :]
            if isinstance(item, Task) and not item.regularisation
        ]
        return error, self._above_primary(kin), np.array(below)

    def _above_primary(self, kin) -> float:
        """Residual of the levels above the primary task: limit and constraint violations, task
        errors (computed once per kinematics: the line search and the merits both ask)."""
        cache = kin.__dict__.setdefault("_above_primary", {})
        key = id(self)
        if key not in cache:
            cache[key] = self._compute_above_primary(kin)
        return cache[key]

    def _compute_above_primary(self, kin) -> float:
        free = self.free_indices(kin.k, *self._frozen)
        lo, hi = self.limit_gaps(kin.config, free, kin.robot_free)
        total = float(max(0.0, np.max(lo, initial=0.0), -np.min(hi, initial=0.0)))
        for item in self.levels:
            if item is self.primary:
                break
            v = self.value(item, kin)
            if isinstance(item, Constraint):
                total += float(max(0.0, -v.min())) if v.shape[0] else 0.0
            else:
                total += float(np.linalg.norm(v))
        return total

    def _line_search(self, config, kin, dv_high, dv_low, error, above, robot_free):
        """Backtrack the lower levels' part of the Gauss–Newton step, dv_high + α dv_low.

        The lower levels (gaze, posture, step preference) move in the null space of the
        levels above them only to first order; with a long chain that second-order motion
        broke the hand task every other iteration and plain Gauss–Newton cycled. A step is
        accepted when it improves the levels above the primary task, or keeps them and the
        primary task from growing; otherwise α is halved (the primary task's own progress,
        dv_high, is never cut). After ``line_search_steps`` halvings α = 0.
        """
        s = self.settings
        alpha = 1.0
        predicted = slope = None
        for attempt in range(s.line_search_steps + 1):
            if attempt == s.line_search_steps:
                alpha = 0.0
            candidate = self.augmented.integrate(config, dv_high + alpha * dv_low)
            kin_c = self.augmented.evaluate(candidate, robot_free=robot_free)
            if s.restore_primary and alpha > 0.0:
                if predicted is None:  # the linear model of the primary along dv_high
                    J = self.primary.compute_jacobian(kin)
                    predicted = self.value(self.primary, kin) + J @ dv_high
                    slope = J @ dv_low
                restored = self._restored(candidate, kin_c, predicted + alpha * slope, robot_free)
                # The correction moves the (Δx, Δy) the levels above did not ask for: it may
                # not cost them anything (no slack), else the plain candidate is tried.
                if (
                    restored is not None
                    and self._above_primary(restored[1]) <= above + 1e-9
                    and self._acceptable(restored[1], error, above)
                ):
                    return restored[0], restored[1], alpha
            if self._acceptable(kin_c, error, above):
                break
            alpha *= 0.5
        return candidate, kin_c, alpha

    def _acceptable(self, kin_c, error: float, above: float) -> bool:
        """The line search's test: the levels above the primary task improve, or they stay
        (within the slack) and the primary task does not grow."""
        s = self.settings
        above_c = self._above_primary(kin_c)
        if above_c < above - 1e-7:
            return True
        return (
            above_c <= max(above, s.line_search_slack) + 1e-9
            and float(np.linalg.norm(self.value(self.primary, kin_c)))
            <= max(error, 0.5 * s.task_tolerance) + 1e-9
        )

    def _restored(
        self, candidate: AugmentedConfiguration, kin_c, predicted: np.ndarray, robot_free: bool
    ):
        """Second-order correction (Nocedal & Wright §15.6) of the primary task after a step.

        The lower levels move in the null space of the primary task only to first order: their
        yaw changes turn the rest of the chain and leave a second-order error on the primary
        (a 0.5 m replan lost 0.2-0.8 mm per iteration that way and took 8 iterations to creep
        back under the tolerance). The correction removes the gap between the primary error
        e_c reached and the error the linearised step predicted (``predicted``, e + J dv: the
        trust region and the clamp of the error stay in force): the least-norm δ over the free
        steps' (Δx, Δy) with J δ = −(e_c − predicted). A footprint, and any frame rigid on it,
        is linear in the (Δx, Δy) at fixed yaws (module doc of :mod:`.augmented_robot`), so one
        such δ removes the gap exactly. Columns that would cross a step limit are held on it
        and the others take the rest. Returns the corrected (configuration, kinematics), which
        the line search tries before the uncorrected candidate, or None (no gap to correct, or
        no room within the limits).
        """
        gap = self.value(self.primary, kin_c) - predicted
        if float(np.sqrt(gap @ gap)) <= 0.05 * self.settings.task_tolerance:
            return None
        k = candidate.num_steps
        free = self.free_indices(k, *self._frozen)
        free = free[(free < 3 * k) & (free % 3 != 2)]
        lo, hi = self.limit_gaps(candidate, free, robot_free)
        J = self.primary.compute_jacobian(kin_c)[:, free]
        moved = np.einsum("ij,ij->i", J, J) > 1e-18  # rows (Δx, Δy) move: not yaws
        delta = _bounded_least_norm(J[moved], -gap[moved], np.minimum(lo, 0.0), np.maximum(hi, 0.0))
        if delta is None:
            return None
        dv = np.zeros(kin_c.nv)
        dv[free] = delta
        corrected = self.augmented.integrate(candidate, dv)
        return corrected, self.augmented.evaluate(corrected, robot_free=robot_free)

    def _relaxing_step_wanted(
        self, k: int, config: AugmentedConfiguration, free: np.ndarray
    ) -> bool:
        """Automatic steps may add one more, and every step is stretched to full length."""
        s = self.settings
        return (
            s.auto_steps and s.relax_stretched and k < s.max_steps and self._stretched(config, free)
        )

    def _stretched(self, config: AugmentedConfiguration, free: np.ndarray) -> bool:
        """The free steps are (nearly) all at their forward limit: the chain cannot extend.

        This is Algorithm 1's local minimum seen early: without it, the optimiser reaches far
        goals by zig-zagging at the lateral and yaw limits instead of taking more steps.
        """
        steps = np.unique(free[free < 3 * config.num_steps] // 3)
        if steps.shape[0] == 0:
            return False
        is_left = self.augmented.is_left(config.num_steps)[2:]
        _, hi = self.limits.bounds(is_left, with_final=True)
        s_tol = self.settings.stretched_tolerance
        at_max = config.steps[steps, 0] >= hi[3 * steps] - s_tol
        return bool(np.mean(at_max) >= self.settings.stretched_fraction)

    def residuals(self, kin) -> dict[str, float]:
        """Per level: ||e|| for tasks, worst violation max(−g, 0) for constraints."""
        out = {}
        for item in self.levels:
            v = self.value(item, kin)
            if isinstance(item, Constraint):
                out[item.name] = float(max(0.0, -v.min())) if v.shape[0] else 0.0
            else:
                out[item.name] = float(np.linalg.norm(v))
        return out


def _bounded_least_norm(
    J: np.ndarray, target: np.ndarray, lower: np.ndarray, upper: np.ndarray, rounds: int = 4
) -> np.ndarray | None:
    """Least-norm δ with J δ = target and lower ≤ δ ≤ upper (lower ≤ 0 ≤ upper), by clamping:
    the entries that cross a bound are held on it and the others solve for the rest. Exact
    when nothing is clamped; None when the free entries run out or the rounds do."""
    delta = np.zeros(J.shape[1])
    held = np.zeros(J.shape[1], dtype=bool)
    for _ in range(rounds):
        open_ = ~held
        if not open_.any() or J.shape[0] == 0:
            return None
        M = J[:, open_]
        G = M @ M.T
        G.flat[:: G.shape[0] + 1] += 1e-12
        delta[open_] = M.T @ np.linalg.solve(G, target - J[:, held] @ delta[held])
        over, under = delta > upper, delta < lower
        if not (over.any() or under.any()):
            return delta
        delta = np.where(over, upper, np.where(under, lower, delta))
        held |= over | under
    return None
