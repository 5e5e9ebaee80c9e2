"""Walk-and-grasp plans on TALOS (Dang ch. 6): the initial plan, online replanning with executed
steps and posture frozen, and the continuous deformation of the plan under goal motion."""

from __future__ import annotations

import numpy as np
import pytest

from footsteps_checks import (
    BALL,
    depth_inside_hull,
    sole_points,
    soles_overlap,
    step_variables_within,
)


def _check_plan(planner, target, hand_axes=(0, 1, 2), hand_tol=1e-3):
    """Everything a user cares about, checked independently of the optimiser's own rows."""
    robot, augmented = planner.robot, planner.augmented
    kin = augmented.evaluate(planner.config)
    foot = augmented.foot
    k = kin.k
    # Hand on the object.
    hand = kin.frame_placement(robot.hand_frames[planner.options.hand])[0]
    assert np.linalg.norm((hand - target)[list(hand_axes)]) < hand_tol
    # Step limits (eq. 2.82) and realistic TALOS steps.
    is_left = kin.is_left[2:]
    assert step_variables_within(planner.config.steps, is_left, planner.limits)
    assert np.all(planner.config.steps[:, 0] <= 0.22 + 1e-6)
    assert np.all(np.abs(planner.config.steps[:, 2]) <= 0.3 + 1e-6)
    # Successive soles never overlap (including the initial stance).
    for i in range(0, k + 1):
        assert not soles_overlap(kin.footprint(i - 1), kin.footprint(i), foot), i
    # The robot stands on its last two footprints, soles flat.
    for i in (k, k - 1):
        side = "left" if kin.is_left[i + 1] else "right"
        p, R = kin.frame_placement(robot.sole_frames[side])
        assert np.allclose(p[:2], kin.footprint(i)[:2], atol=1e-4)
        assert abs(p[2] - augmented.stance.floor_z) < 1e-4
        assert abs(R[2, 2] - 1.0) < 1e-6
    # CoM inside the final support polygon, with the margin.
    depth = depth_inside_hull(kin.com()[:2], [kin.footprint(k), kin.footprint(k - 1)], foot)
    assert depth >= planner.options.com_margin - 1e-5
    # Joint limits.
    q = planner.config.q_robot
    assert np.all(q[7:] >= robot.model.lowerPositionLimit[7:] - 1e-6)
    assert np.all(q[7:] <= robot.model.upperPositionLimit[7:] + 1e-6)


def test_initial_plan_reaches_the_ball_within_every_constraint(grasp_planner_factory):
    planner = grasp_planner_factory()
    report = grasp_planner_factory.initial_report
    assert report.converged
    _check_plan(planner, BALL)
    # Algorithm 1 found the number of steps: a 2 m walk needs at least ~1.6 m / 0.22 m.
    assert 7 <= planner.config.num_steps <= 12
    # The robot arrives facing the ball's direction, looking at it.
    kin = planner.augmented.evaluate(planner.config)
    heading = np.arctan2(BALL[1], BALL[0])
    assert abs(kin.footprint(kin.k)[2] - heading) < 0.02
    assert np.linalg.norm(planner.gaze.compute_error(kin)) < 0.01


def test_frozen_replan_keeps_executed_steps_and_posture(grasp_planner_factory):
    planner = grasp_planner_factory()
    before = planner.config.copy()
    target = BALL + np.array([0.08, -0.05, 0.0])
    report = planner.replan(target, executed_steps=3, posture_frozen=True)
    assert report.converged
    assert np.array_equal(planner.config.steps[:3], before.steps[:3])
    # The posture (joints) is untouched; the free-flyer is re-expressed if a step was added.
    assert np.array_equal(planner.config.q_robot[7:], before.q_robot[7:])
    _check_plan(planner, target, hand_axes=(0, 1))


def test_full_replan_moves_steps_and_posture(grasp_planner_factory):
    planner = grasp_planner_factory()
    before = planner.config.copy()
    target = BALL + np.array([-0.1, 0.1, 0.05])  # also higher: only the posture can do it
    report = planner.replan(target, executed_steps=2, posture_frozen=False)
    assert report.converged
    assert np.array_equal(planner.config.steps[:2], before.steps[:2])
    assert not np.allclose(planner.config.q_robot, before.q_robot)
    _check_plan(planner, target)


def test_moved_goal_deforms_the_plan_continuously(grasp_planner_factory):
    """Dang fig. 3.5: footprints move by an amount proportional to the goal modification."""
    planner = grasp_planner_factory()
    initial = planner.augmented.footprints(planner.config.steps)
    direction = np.array([0.6, 0.8, 0.0])
    ratios = []
    for eps in (0.005, 0.01, 0.02, 0.04):
        planner = grasp_planner_factory()
        report = planner.replan(BALL + eps * direction, posture_frozen=True)
        assert report.converged and report.steps_added == 0
        moved = planner.augmented.footprints(planner.config.steps)
        displacement = np.max(np.linalg.norm(moved[:, :2] - initial[:, :2], axis=1))
        ratios.append(displacement / eps)
    # Lipschitz and nearly linear: no footprint jumps.
    assert max(ratios) < 3.0
    assert max(ratios) / min(ratios) < 1.5


def test_replanning_an_unchanged_target_changes_nothing(grasp_planner_factory):
    planner = grasp_planner_factory()
    before = planner.augmented.footprints(planner.config.steps)
    planner.replan(BALL, posture_frozen=True)
    after = planner.augmented.footprints(planner.config.steps)
    assert np.allclose(before, after, atol=2e-3)


def test_bad_hand_is_rejected(robot, stance):
    from marionette.footsteps.errors import InvalidProblem
    from marionette.footsteps.planner import GraspPlanner, GraspPlannerOptions

    with pytest.raises(InvalidProblem, match="hand must be one of"):
        GraspPlanner(robot, stance, BALL, options=GraspPlannerOptions(hand="third"))
    planner = GraspPlanner(robot, stance, BALL)
    with pytest.raises(InvalidProblem, match="executed_steps must be >= 0"):
        planner.replan(BALL, executed_steps=-1)


def test_frozen_replan_adds_steps_exactly_when_the_stance_is_beyond_the_chains_reach(
    grasp_planner_factory,
):
    """Algorithm 1 in replanning: the free steps can lengthen by Σ (max_length − Δx_i) at most
    (their heading unchanged); a ball moved farther ahead than that needs new steps, a ball
    moved less does not."""
    planner = grasp_planner_factory()
    free = planner.config.steps[:-1]  # the last step belongs to the posture
    room = float(np.sum(planner.limits.default.max_length - free[:, 0]))
    heading = np.array(
        [np.cos(planner.config.steps[:, 2].sum()), np.sin(planner.config.steps[:, 2].sum()), 0.0]
    )
    for move, needs_steps in ((0.5 * room, False), (2.0 * room, True)):
        planner = grasp_planner_factory()
        target = BALL + move * heading
        report = planner.replan(target, executed_steps=0, posture_frozen=True)
        assert report.converged
        assert (report.steps_added > 0) == needs_steps, (move, room, report.steps_added)
        _check_plan(planner, target, hand_axes=(0, 1))


@pytest.mark.slow
def test_replanning_beside_obstacles_adds_no_steps_for_a_closer_ball(robot, stance):
    """Moving the ball 0.5 m back towards the robot, beside two discs, never needs a longer
    walk: the replan keeps at most the initial plan's steps plus the pair a full replan's chain
    may add, and stays clear of the discs (their linearised rows once made the chain's reach
    check append steps up to the 40-step cap)."""
    from marionette.footsteps.obstacles import CircleObstacle
    from marionette.footsteps.planner import GraspPlanner

    discs = [
        CircleObstacle([1.0, 0.0], 0.12, buffer=0.03),
        CircleObstacle([1.5, -0.35], 0.1, buffer=0.03),
    ]
    planner = GraspPlanner(robot, stance, BALL, obstacles=discs)
    assert planner.plan().converged
    initial_steps = planner.config.num_steps
    target = BALL + 0.5 * np.array([np.cos(np.radians(182.0)), np.sin(np.radians(182.0)), 0.0])
    report = planner.replan(target, executed_steps=0, posture_frozen=False)
    assert report.converged
    assert planner.config.num_steps <= initial_steps + 2
    _check_plan(planner, target)
    kin = planner.augmented.evaluate(planner.config)
    for i in range(1, kin.k + 1):
        points = sole_points(kin.footprint(i), planner.augmented.foot)
        for disc in discs:
            gap = np.min(np.linalg.norm(points - disc.center, axis=1))
            assert gap >= disc.radius + disc.buffer - 2e-3, (i, disc.center)
