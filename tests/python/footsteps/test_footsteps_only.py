"""Footsteps alone (Dang §3.3): automatic number of steps (Algorithm 1) and local deformation
around obstacle regions (§3.2.2, fig. 3.5)."""

from __future__ import annotations

import numpy as np
import pytest

from footsteps_checks import TALOS_FOOT, sole_points, soles_overlap, step_variables_within
from marionette.footsteps.augmented_robot import (
    AugmentedConfiguration,
    AugmentedRobot,
    planar_compose,
)
from marionette.footsteps.constraints import (
    FINAL_STANCE,
    FootNonOverlap,
    FootprintPoseTask,
    ObstacleAvoidance,
    StanceGoalTask,
    StepLimits,
    StepPreferenceTask,
)
from marionette.footsteps.obstacles import CircleObstacle
from marionette.footsteps.optimizer import FootstepOptimizer, OptimizerSettings


def _plan(stance, goal, obstacles=(), config=None):
    augmented = AugmentedRobot(None, stance, "right", TALOS_FOOT)
    task = StanceGoalTask(goal)
    levels = [FootNonOverlap()]
    if obstacles:
        levels.append(ObstacleAvoidance(list(obstacles)))
    levels += [task, StepPreferenceTask(0.17)]
    limits = StepLimits(final=FINAL_STANCE)
    optimizer = FootstepOptimizer(augmented, levels, task, limits)
    config, report = optimizer.solve(config or augmented.neutral_configuration(0))
    return augmented, config, report, limits


@pytest.mark.parametrize("distance", [0.5, 1.0, 2.0, 3.0])
def test_algorithm_1_finds_enough_steps_for_the_distance(stance, distance):
    augmented, config, report, limits = _plan(stance, [distance, 0.0, 0.0])
    assert report.converged
    k = config.num_steps
    # Each foot advances at most 2 × 0.22 m per two steps: the least number of steps is
    # about distance / 0.22; Algorithm 1 should not need many more than that.
    assert distance / 0.22 <= k <= distance / 0.22 + 4
    fp = augmented.footprints(config.steps)
    assert np.allclose(0.5 * (fp[-1, :2] + fp[-2, :2]), [distance, 0.0], atol=2e-3)
    assert step_variables_within(config.steps, augmented.is_left(k)[2:], limits)


def test_plan_around_a_disc_keeps_every_sole_out_of_its_buffer(stance):
    disc = CircleObstacle([1.0, 0.05], 0.12, buffer=0.03)
    augmented, config, report, _ = _plan(stance, [2.0, 0.0, 0.0], [disc])
    assert report.converged
    fp = augmented.footprints(config.steps)
    for i, pose in enumerate(fp):
        d = np.min(np.linalg.norm(sole_points(pose, TALOS_FOOT) - disc.center, axis=1))
        assert d >= disc.radius + disc.buffer - 2e-3, i
        if i:
            assert not soles_overlap(fp[i - 1], pose, TALOS_FOOT)


def test_moving_the_obstacle_deforms_the_steps_locally(stance):
    """Fig. 3.5: moving one obstacle a little moves the nearby steps a little, not the plan."""
    disc = CircleObstacle([1.0, 0.05], 0.12, buffer=0.03)
    augmented, config, _, _ = _plan(stance, [2.0, 0.0, 0.0], [disc])
    before = augmented.footprints(config.steps)
    moved = CircleObstacle([1.0, 0.09], 0.12, buffer=0.03)
    _, config2, report, _ = _plan(stance, [2.0, 0.0, 0.0], [moved], config=config.copy())
    assert report.converged and config2.num_steps == config.num_steps
    after = augmented.footprints(config2.steps)
    displacement = np.linalg.norm(after[:, :2] - before[:, :2], axis=1)
    assert displacement.max() < 0.15  # a 4 cm move does not reshuffle the plan
    for pose in after:
        d = np.min(np.linalg.norm(sole_points(pose, TALOS_FOOT) - moved.center, axis=1))
        assert d >= moved.radius + moved.buffer - 2e-3


def test_second_order_correction_puts_the_goal_back_with_the_yaws_untouched(stance):
    """A lower level's step lies in the null space of the goal's Jacobian, but turning the yaws
    moves the far end of the chain at second order. The correction (``restore_primary``) must
    put the last footprint back where the linearised step predicted, moving only the steps'
    (Δx, Δy), within their limits. Reference: the footprints composed step by step."""
    augmented = AugmentedRobot(None, stance, "right", TALOS_FOOT)
    steps = np.array([[0.15, -0.17 if i % 2 == 0 else 0.17, 0.0] for i in range(6)])
    config = AugmentedConfiguration(steps)
    goal = FootprintPoseTask(None, augmented.footprints(steps)[-1], weights=(1.0, 1.0, 1.0))
    limits = StepLimits()
    optimizer = FootstepOptimizer(
        augmented,
        [FootNonOverlap(), goal, StepPreferenceTask(0.17)],
        goal,
        limits,
        OptimizerSettings(restore_primary=True),
    )
    optimizer._frozen = (0, False)  # set by solve(); here one step by hand
    kin = augmented.evaluate(config)
    J = goal.compute_jacobian(kin)
    rng = np.random.default_rng(3)
    dv = rng.normal(size=18) * np.tile([0.01, 0.01, 0.08], 6)
    dv -= np.linalg.pinv(J) @ (J @ dv)  # null space of the goal: no first-order move
    candidate = augmented.integrate(config, dv)

    def last_footprint(steps):
        pose = augmented.root
        for step in steps:
            pose = planar_compose(pose, step)
        return pose

    assert np.linalg.norm(last_footprint(candidate.steps) - goal.target) > 1e-3
    predicted = goal.compute_error(kin) + J @ dv  # = 0 here
    corrected, _ = optimizer._restored(candidate, augmented.evaluate(candidate), predicted, False)
    assert np.allclose(last_footprint(corrected.steps), goal.target + predicted, atol=1e-9)
    assert np.array_equal(corrected.steps[:, 2], candidate.steps[:, 2])
    assert step_variables_within(corrected.steps, augmented.is_left(6)[2:], limits)
