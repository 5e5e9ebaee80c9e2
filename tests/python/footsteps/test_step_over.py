"""Stepping over a bar (Dang ch. 5): removal of infeasible steps, the crossing, Algorithm 3."""

from __future__ import annotations

import numpy as np
import pytest

from footsteps_checks import sole_points, soles_overlap
from marionette.footsteps.augmented_robot import planar_relative, rotation_2d
from marionette.footsteps.obstacles import Bar
from marionette.footsteps.step_over import StepOverPlanner
from marionette.footsteps.swing import bar_clearance

GOAL = np.array([2.0, 0.0, 0.0])


@pytest.fixture
def planner(stance):
    bar = Bar([1.0, 0.0], np.pi / 2, 0.02, 2.0, buffer=0.03)
    p = StepOverPlanner(stance, GOAL, bar)
    report = p.plan()
    assert report.converged
    return p


def _gap_to_bar(pose, bar, foot):
    """Brute force: distance from the sole to the bar's floor band [m]."""
    local = (sole_points(pose, foot) - bar.center) @ rotation_2d(bar.yaw)
    return np.min(np.hypot(np.maximum(np.abs(local[:, 0]) - 0.5 * bar.length, 0.0),
                           np.maximum(np.abs(local[:, 1]) - bar.radius, 0.0)))


def _check(planner):
    plan = planner.result()
    foot, bar = planner.foot, planner.bar
    poses = [np.array([p[0], p[1], p[3]]) for p in plan.footprints()]
    for i, pose in enumerate(poses):
        assert _gap_to_bar(pose, bar, foot) >= bar.buffer - 2e-3, i
        if i:
            assert not soles_overlap(poses[i - 1], pose, foot)
    last = plan.steps[-1].pose
    mid = 0.5 * (plan.steps[-1].pose[:2] + plan.steps[-2].pose[:2])
    assert np.allclose(mid, GOAL[:2], atol=3e-3) and abs(last[3] - GOAL[2]) < 5e-3
    # Exactly two swings cross the bar, each through passage points clearing it (eq. 5.1).
    crossing = [s for s in plan.steps if s.via.shape[0]]
    assert len(crossing) == 2
    n = bar.normal()
    half = 0.5 * foot.length
    for step in crossing:
        i = step.index
        lift = plan.steps[i - 2].pose if i >= 2 else plan.stance["left" if step.is_left
                                                                 else "right"]
        points = np.vstack([lift[:3], step.via, step.pose[:3]])
        path = np.vstack([np.linspace(a, b, 100) for a, b in zip(points[:-1], points[1:])])
        s = (path[:, :2] - bar.center) @ n
        # The soles cross nearly perpendicular to the bar here: d1 = d2 = half length.
        assert np.min(bar_clearance(s, path[:, 2], 0.0, bar.radius, bar.radius, half, half)) \
            > 0.0
    return plan


def test_initial_plan_steps_over_the_bar(planner):
    plan = _check(planner)
    before, after = planner.crossing
    assert plan.steps[before - 1].pose[0] < 1.0 < plan.steps[after - 1].pose[0]


@pytest.mark.parametrize("move", [(0.03, 0.0, 0.0), (0.06, 0.05, 0.08), (-0.05, -0.03, -0.1)])
def test_moved_bar_keeps_the_crossing_steps_fixed_relative_to_it(planner, move):
    """Algorithm 3: the two footprints straddling the bar move with the bar."""
    kin = planner.augmented.evaluate(planner.config)
    before = {i: planar_relative(planner.bar.pose(), kin.footprint(i)) for i in planner.crossing}
    moved = planner.bar.moved_to(planner.bar.center + np.array(move[:2]),
                                 planner.bar.yaw + move[2])
    report = planner.update_bar(moved, executed_steps=1)
    assert report.converged
    kin = planner.augmented.evaluate(planner.config)
    for i in planner.crossing:
        assert np.allclose(planar_relative(moved.pose(), kin.footprint(i)), before[i], atol=1e-4)
    _check(planner)


def test_bar_moved_beyond_the_free_steps_reach_leaves_a_safe_plan_without_new_steps(planner):
    """Algorithm 3 cannot hold the crossing footprints on a bar moved 15 cm farther once a step
    is taken (the steps before it are near full length): the replan must stop within its
    iteration budget with the soles still clear of the bar (obstacles rank above the crossing
    targets), and not append steps at the end of the chain (Algorithm 1 serves the goal)."""
    moved = planner.bar.moved_to(planner.bar.center + np.array([0.15, 0.0]), planner.bar.yaw)
    k = planner.config.num_steps
    report = planner.update_bar(moved, executed_steps=1)
    assert report.steps_added == 0 and planner.config.num_steps == k
    assert report.iterations <= planner.options.replan_max_iterations
    plan = planner.result()
    for i, p in enumerate(plan.footprints()):
        assert _gap_to_bar(np.array([p[0], p[1], p[3]]), moved, planner.foot) >= moved.buffer - 2e-3, i
