"""Footstep optimisation (Dang 2012 ch. 2.5, 3, 5, 6): the robot plus a virtual kinematic chain
of planar joints, one per step, solved as a prioritised equality/inequality problem.

* :mod:`.augmented_robot` — robot + k virtual planar joints (eq. 2.82–2.83), analytic Jacobians;
* :mod:`.constraints` — step limits, non-overlap, obstacle regions, CoM, hand, gaze, posture;
* :mod:`.hierarchy` — Kanoun's cascade of least-squares / QP levels (eq. 2.77–2.81, proxsuite);
* :mod:`.optimizer` — Gauss–Newton over the cascade, automatic number of steps (Algorithm 1);
* :mod:`.planner` — walk-and-grasp plans and online replanning (Algorithms 2 and 4);
* :mod:`.step_over` — stepping over a bar (ch. 5, Algorithm 3, eq. 5.1 in :mod:`.swing`);
* :mod:`.plan`, :mod:`.plot`, :mod:`.node`, :mod:`.cli` — output, figures, the LCM process.
"""

from marionette.footsteps.augmented_robot import AugmentedConfiguration, AugmentedRobot, Stance
from marionette.footsteps.errors import FootstepError, InvalidProblem, PlanningFailed
from marionette.footsteps.obstacles import Bar, CircleObstacle, RectangleObstacle
from marionette.footsteps.plan import Footstep, FootstepPlan, StepTiming
from marionette.footsteps.planner import GraspPlanner, GraspPlannerOptions
from marionette.footsteps.step_over import StepOverPlanner

__all__ = [
    "AugmentedConfiguration",
    "AugmentedRobot",
    "Bar",
    "CircleObstacle",
    "Footstep",
    "FootstepError",
    "FootstepPlan",
    "GraspPlanner",
    "GraspPlannerOptions",
    "InvalidProblem",
    "PlanningFailed",
    "RectangleObstacle",
    "Stance",
    "StepOverPlanner",
    "StepTiming",
]
