"""Footsteps alone (Dang §3.3): automatic number of steps (Algorithm 1) and local deformation
around obstacle regions (§3.2.2, fig. 3.5)."""

from __future__ import annotations

import numpy as np
import pytest

from footsteps_checks import sole_points, soles_overlap, step_variables_within
from marionette.footsteps.augmented_robot import AugmentedRobot
from marionette.footsteps.constraints import (FINAL_STANCE, FootNonOverlap, ObstacleAvoidance,
                                              StanceGoalTask, StepLimits, StepPreferenceTask)
from marionette.footsteps.obstacles import CircleObstacle
from marionette.footsteps.optimizer import FootstepOptimizer
from marionette.footsteps.robot_model import TALOS_FOOT


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
    assert displacement.max() < 0.15           # a 4 cm move does not reshuffle the plan
    for pose in after:
        d = np.min(np.linalg.norm(sole_points(pose, TALOS_FOOT) - moved.center, axis=1))
        assert d >= moved.radius + moved.buffer - 2e-3
