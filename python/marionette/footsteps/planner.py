"""Footsteps and final posture for a walk-and-grasp task (Dang ch. 6, Algorithms 1, 2 and 4).

The problem on the augmented robot, in priority order (Dang §6.1.1; all constraints above all
tasks):

    (eq) feet on the last two footprints (closure of the augmented robot; posture free only)
    step limits (eq. 2.82) and joint limits as variable bounds
    (in) successive footprints do not overlap
    (in) footprints outside obstacle regions + buffer (§3.2.2)
    (in) CoM inside the final support polygon (posture free only)
    (eq) hand task (grasp point on the object)
    (eq) gaze task (camera axis on the object)
    (eq) the final stance faces the approach direction (start → object)
    (eq) the object sits at a nominal reach from the final stance (in front, hand side)
    (eq) reference posture (posture free only)

:meth:`GraspPlanner.plan` starts from zero virtual links and lets Algorithm 1 add them;
:meth:`GraspPlanner.replan` warm-starts from the current solution with the executed steps
frozen (Algorithm 2 line 11) and, optionally, the posture frozen (§6.2.2, table 6.2).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from marionette.footsteps.augmented_robot import (
    AugmentedConfiguration,
    AugmentedRobot,
    Stance,
    rotation_2d,
)
from marionette.footsteps.constraints import (
    FINAL_STANCE,
    ComInSupportPolygon,
    Constraint,
    FacingTask,
    FeetOnFootprints,
    FootNonOverlap,
    FootprintPoseTask,
    FramePositionTask,
    GazeTask,
    ObstacleAvoidance,
    PostureTask,
    ReachTask,
    StepBounds,
    StepLimits,
    StepPreferenceTask,
    Task,
)
from marionette.footsteps.errors import InvalidProblem, PlanningFailed
from marionette.footsteps.final_pose import solve_final_pose
from marionette.footsteps.obstacles import Obstacle
from marionette.footsteps.optimizer import FootstepOptimizer, OptimizerSettings, SolveReport
from marionette.footsteps.plan import FootstepPlan, StepTiming
from marionette.footsteps.robot_model import RobotDescription


def default_first_side(stance: Stance, target_xy: np.ndarray) -> str:
    """The foot on the side of the target moves first (right when straight ahead)."""
    mid = 0.5 * (stance.left[:2] + stance.right[:2])
    heading = 0.5 * (stance.left[2] + stance.right[2])
    lateral = (rotation_2d(heading).T @ (np.asarray(target_xy) - mid))[1]
    return "left" if lateral > 0.0 else "right"


def posture_band_limits(
    robot: RobotDescription, band: dict[str, tuple[float, float]]
) -> tuple[np.ndarray, np.ndarray]:
    """Joint limits (nq each) of reference + band for joints whose name starts with a key."""
    model = robot.model
    lower, upper = np.full(model.nq, -np.inf), np.full(model.nq, np.inf)
    for j in range(2, model.njoints):
        name = model.names[j]
        for prefix, (lo, hi) in band.items():
            if name.startswith(prefix):
                iq = model.idx_qs[j]
                lower[iq] = robot.reference_posture[iq] + lo
                upper[iq] = robot.reference_posture[iq] + hi
    return lower, upper


@dataclass
class GraspPlannerOptions:
    hand: str = "right"
    gaze: bool = True
    non_overlap_margin: float = 0.02  # [m] between successive soles
    com_margin: float = 0.03  # [m] CoM inside the final support polygon
    nominal_width: float = 0.17  # [m] preferred lateral distance of the soles (a 1.7 m humanoid)
    replan_settle_ratio: float = 0.02  # replans stop when lower levels improve less than this
    # Where the object sits in the final stance frame: forward, towards the hand's side [m].
    reach_offset: tuple[float, float] = (0.45, 0.25)
    # Comfort band of the final posture around the reference [rad], by joint-name prefix: the
    # legs stay near half-sitting and the torso does not fold, so that far objects are reached
    # by walking (Algorithm 1 adds steps) rather than by leaning, and the pattern generator's
    # straight-posture assumption holds until the reach.
    posture_band: dict[str, tuple[float, float]] = field(
        default_factory=lambda: {
            "leg_": (-0.3, 0.3),
            "torso_1": (-0.3, 0.3),
            "torso_2": (-0.05, 0.6),
        }
    )


class GraspPlanner:
    """Walk to an object and reach it with one hand: footsteps + final posture (see module)."""

    def __init__(
        self,
        robot: RobotDescription,
        stance: Stance,
        target: np.ndarray,
        obstacles: list[Obstacle] | None = None,
        first_side: str | None = None,
        limits: StepLimits | None = None,
        options: GraspPlannerOptions | None = None,
        settings: OptimizerSettings | None = None,
        timing: StepTiming | None = None,
    ) -> None:
        self.robot = robot
        self.options = options or GraspPlannerOptions()
        if self.options.hand not in robot.hand_frames:
            raise InvalidProblem(
                f"hand must be one of {sorted(robot.hand_frames)}, got {self.options.hand!r}"
            )
        target = np.asarray(target, dtype=float)
        side = first_side or default_first_side(stance, target[:2])
        self.augmented = AugmentedRobot(robot, stance, side)
        self.obstacles = list(obstacles or [])
        self.limits = limits or StepLimits(final=FINAL_STANCE)
        self.settings = settings or OptimizerSettings()
        self.timing = timing or StepTiming()
        self.hand = FramePositionTask(robot.hand_frames[self.options.hand], target)
        self.gaze = GazeTask(robot.camera_frame, target)
        self.facing = FacingTask(target, 0.5 * (stance.left[:2] + stance.right[:2]))
        hand_sign = 1.0 if self.options.hand == "left" else -1.0
        self.reach = ReachTask(
            target, (self.options.reach_offset[0], hand_sign * self.options.reach_offset[1])
        )
        joints = np.setdiff1d(np.arange(6, robot.model.nv), robot.frozen_velocity_indices())
        self.posture = PostureTask(robot.reference_posture, joints)
        self._posture_limits = posture_band_limits(robot, self.options.posture_band)
        self.config: AugmentedConfiguration = self.augmented.neutral_configuration(0)
        self.frozen_steps = 0
        self.last_report: SolveReport | None = None

    @property
    def target(self) -> np.ndarray:
        return self.hand.target

    def set_target(self, target) -> None:
        """Algorithm 4 line 6: update the hand and gaze tasks."""
        self.hand.set_target(target)
        self.gaze.set_target(target)
        self.facing.set_target(target)
        self.reach.set_target(target)

    def set_obstacles(self, obstacles: list[Obstacle]) -> None:
        self.obstacles = list(obstacles)

    def optimizer(self, posture_frozen: bool) -> FootstepOptimizer:
        first = self.frozen_steps + 1
        levels: list[Constraint | Task] = []
        if not posture_frozen:
            levels.append(FeetOnFootprints())
        levels.append(FootNonOverlap(self.options.non_overlap_margin, first_step=first))
        if self.obstacles:
            levels.append(ObstacleAvoidance(self.obstacles, first_step=first))
        if not posture_frozen:
            levels.append(ComInSupportPolygon(self.options.com_margin))
        # With the posture frozen, the hand's height is fixed: only its floor position is a
        # task (else Algorithm 1 would add steps to chase an unreachable height).
        self.hand.axes = np.array([0, 1]) if posture_frozen else np.array([0, 1, 2])
        levels.append(self.hand)
        if self.options.gaze:
            levels.append(self.gaze)
        levels.append(self.facing)
        if not posture_frozen:
            levels += [self.reach, self.posture]
        last = -1 if posture_frozen else None  # the frozen posture owns the last step
        levels.append(StepPreferenceTask(self.options.nominal_width, first, last))
        return FootstepOptimizer(
            self.augmented, levels, self.hand, self.limits, self.settings, self._posture_limits
        )

    def plan(self) -> SolveReport:
        """Initial plan (Algorithm 1): from zero virtual links, posture free."""
        self.config = self.augmented.neutral_configuration(0)
        self.frozen_steps = 0
        return self._solve(posture_frozen=False, relax_stretched=True)

    def replan(
        self, target=None, executed_steps: int | None = None, posture_frozen: bool = True
    ) -> SolveReport:
        """Replan after a target move / step progress (Algorithm 4), warm-started.

        ``executed_steps``: steps already started (executed or in progress); they are frozen.
        """
        if target is not None:
            self.set_target(target)
        if executed_steps is not None:
            if executed_steps < 0:
                raise InvalidProblem(f"executed_steps must be >= 0, got {executed_steps}")
            self.frozen_steps = executed_steps
        if posture_frozen and self.config.num_steps - 1 <= self.frozen_steps:
            # Every step but the posture-bound last one is frozen: nothing would move. Add two
            # in-place steps (one would swap the feet under the frozen robot).
            while self.config.num_steps - 1 <= self.frozen_steps:
                self.config = self.augmented.add_step(self.augmented.add_step(self.config))
        if posture_frozen:
            return self._solve_frozen()
        if self.config.num_steps - 2 >= self.frozen_steps:
            return self._solve_full_replan()
        return self._solve(posture_frozen)

    def _solve_frozen(self) -> SolveReport:
        """Posture frozen: the robot is rigid on its last footprint P_k, so its tasks depend on
        P_k only. Solve them over P_k's 3 dofs (:mod:`.final_pose`), then make the chain reach
        that stance (footsteps only, Dang §3.3) with the same constraints above it."""
        start = time.perf_counter()
        robot_frames = self.augmented._robot_kinematics(self.config.require_q_robot())["frames"]
        frames_L = {name: (p, R) for name, (p, R, _) in robot_frames.items()}
        self.hand.axes = np.array([0, 1])
        tasks = [self.hand] + ([self.gaze] if self.options.gaze else []) + [self.facing]
        pose0 = self.augmented.footprints(self.config.steps)[-1]
        stance, pose_iterations = solve_final_pose(
            tasks, pose0, frames_L, self.augmented.stance.floor_z, tolerance=1e-4
        )
        report = self._reach_stance(stance)
        report.pose_iterations = pose_iterations
        report.time_s = time.perf_counter() - start
        self.last_report = report
        return report

    def _reach_stance(self, stance: np.ndarray) -> SolveReport:
        """The chain, footsteps only, brings its last footprint to ``stance`` (x, y, θ) with
        the last step Δ_k fixed (it belongs to the posture)."""
        # On the last footprint: steps are added in pairs here, so the robot keeps its sides.
        goal = FootprintPoseTask(None, stance, weights=(1.0, 1.0, 1.0), name="robot_stance")
        goal.max_step = 0.6  # the chain is near its solution: larger Gauss–Newton steps
        first = self.frozen_steps + 1
        levels: list[Constraint | Task] = [
            FootNonOverlap(self.options.non_overlap_margin, first_step=first)
        ]
        if self.obstacles:
            levels.append(ObstacleAvoidance(self.obstacles, first_step=first))
        preference = StepPreferenceTask(self.options.nominal_width, first, -1)
        # Replans start from a plan whose preference level has converged: should the exact
        # active-set paths fail, scale its step (best effort) rather than solve a proxsuite QP.
        preference.best_effort = True
        levels += [goal, preference]
        # Replanning keeps the plan's step count unless the stance is out of reach (Algorithm 1
        # proper; the initial plan alone adds a step when it converged fully stretched), and
        # stops once the lower levels improve by less than 2 % per iteration: the next replan
        # warm-starts from here anyway.
        # The stance error mixes metres and radians; a hand ~0.6 m from the sole turns θ errors
        # into position errors, hence a tolerance well below the hand's.
        # Footprints are linear in the (Δx, Δy) of the steps at fixed yaws: only the yaws need
        # the trust region of the posture-free problem; a wider one on (Δx, Δy) lets new steps
        # reach their length in one iteration (0.5 m replans: 3.8 -> 3.4 iterations on average).
        # The step preference's yaws break the stance at second order (the chain turns about
        # them); each step's second-order correction restores it (0.5 m: 3.7 -> 2.8 iterations).
        # Without obstacles the reach check adds steps when the linearised chain misses the
        # stance by more than 1 mm: the yaws' curvature only lengthens a miss, and of the
        # 0.5 m replans of the benchmark every one that missed by 2.2-58 mm added its steps
        # anyway, 3-4 iterations later, while a 0.9 mm miss was closed by the iterations.
        # An obstacle's linearised rows block directions the chain can still take around it
        # (a 1 mm check added steps there that the iterations did not need): the default then.
        reach_tolerance = self.settings.reach_tolerance if self.obstacles else 1e-3
        settings = dataclasses.replace(
            self.settings,
            relax_stretched=False,
            reach_check=True,
            trust_region_steps=0.25,
            settle_ratio=self.options.replan_settle_ratio,
            task_tolerance=0.2 * self.settings.task_tolerance,
            blocked_iterations=1,
            restore_primary=True,
            reach_tolerance=reach_tolerance,
        )
        optimizer = FootstepOptimizer(self.augmented, levels, goal, self.limits, settings)
        self.config, report = optimizer.solve(self.config, self.frozen_steps, posture_frozen=True)
        return report

    def _solve_full_replan(self) -> SolveReport:
        """Posture free: the robot tasks depend on the posture and on the last two footprints
        only. Solve them on a two-step augmented robot whose first step is unbounded (the
        final stance free in the world, the last step within its final-stance bounds), then
        make the chain reach that stance. Exact while the chain's own constraints do not bind
        at the stance; otherwise Algorithm 1 adds steps to the chain."""
        start = time.perf_counter()
        k = self.config.num_steps
        fp = self.augmented.footprints(self.config.steps)  # rows: footprints -1..k
        root, other = fp[k - 1], fp[k - 2]  # P_(k-2), P_(k-3)
        last_side = self.augmented.side_of(k)
        stance = Stance(
            root if last_side == "left" else other,
            other if last_side == "left" else root,
            self.augmented.stance.floor_z,
        )
        sub = AugmentedRobot(self.robot, stance, self.augmented.side_of(k - 1))
        sub_config = AugmentedConfiguration(
            self.config.steps[k - 2 :].copy(), self.config.require_q_robot().copy()
        )
        free_step = StepBounds(-10.0, 10.0, -10.0, 10.0, np.pi, np.pi)  # P_(k-1) anywhere
        limits = StepLimits(default=free_step, final=self.limits.final)
        self.hand.axes = np.array([0, 1, 2])
        levels: list[Constraint | Task] = [
            FeetOnFootprints(),
            FootNonOverlap(self.options.non_overlap_margin, first_step=2),
        ]
        if self.obstacles:
            levels.append(ObstacleAvoidance(self.obstacles, first_step=1))
        levels += [ComInSupportPolygon(self.options.com_margin), self.hand]
        if self.options.gaze:
            levels.append(self.gaze)
        levels += [
            self.facing,
            self.reach,
            self.posture,
            StepPreferenceTask(self.options.nominal_width, 2, 2),
        ]
        # Two steps, not a long chain: wider trust region and error clamp than the chain's.
        # The closure level may be left at 0.1 mm when lower levels cannot settle (a task the
        # limits cannot satisfy keeps pushing); the iteration budget bounds the replan time.
        settings = dataclasses.replace(
            self.settings,
            auto_steps=False,
            settle_ratio=self.options.replan_settle_ratio,
            trust_region_steps=0.3,
            trust_region_yaw=0.2,
            constraint_tolerance=1e-4,
            max_iterations=100,
        )
        optimizer = FootstepOptimizer(
            sub, levels, self.hand, limits, settings, self._posture_limits
        )
        self.hand.max_step = 0.25
        try:
            sub_config, robot_report = optimizer.solve(sub_config)
        finally:
            del self.hand.max_step
        steps = self.config.steps.copy()
        steps[k - 1] = sub_config.steps[1]
        self.config = AugmentedConfiguration(steps, sub_config.q_robot)
        report = self._reach_stance(sub.footprints(sub_config.steps)[-1])
        report.pose_iterations = robot_report.iterations
        report.qp_solves += robot_report.qp_solves
        report.converged = report.converged and robot_report.converged
        report.level_residuals.update(robot_report.level_residuals)
        report.time_s = time.perf_counter() - start
        self.last_report = report
        return report

    def _solve(self, posture_frozen: bool, relax_stretched: bool = False) -> SolveReport:
        optimizer = self.optimizer(posture_frozen)
        optimizer.settings = dataclasses.replace(
            self.settings,
            relax_stretched=relax_stretched,
            settle_ratio=self.settings.settle_ratio
            if relax_stretched
            else self.options.replan_settle_ratio,
        )
        self.config, report = optimizer.solve(self.config, self.frozen_steps, posture_frozen)
        self.last_report = report
        return report

    def result(self) -> FootstepPlan:
        """The current solution as a footstep plan (world soles, sides, timing)."""
        kin = self.augmented.evaluate(self.config, robot_free=False)
        return FootstepPlan.from_footprints(
            kin.footprints, kin.is_left, self.augmented.stance.floor_z, self.timing
        )

    def require_converged(self, report: SolveReport) -> None:
        if not report.converged:
            raise PlanningFailed(
                f"hand task not reached: error {report.primary_error:.4f} m "
                f"after {report.iterations} iterations, "
                f"{self.config.num_steps} steps"
            )
