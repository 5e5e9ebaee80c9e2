"""Constraint and task Jacobians against central finite differences, and the geometry of the
constraints against brute-force references (dense sampling of the shapes)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from footsteps_checks import TALOS_FOOT
from marionette.footsteps.augmented_robot import AugmentedRobot, Stance, rotation_2d
from marionette.footsteps.constraints import (
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
    StanceGoalTask,
    StepBounds,
    StepPreferenceTask,
    sole_clearance,
)
from marionette.footsteps.errors import InvalidProblem
from marionette.footsteps.final_pose import RigidStanceKinematics
from marionette.footsteps.obstacles import Bar, CircleObstacle, RectangleObstacle

OBSTACLES = [
    CircleObstacle([0.3, 0.2], 0.1),
    RectangleObstacle([0.4, -0.3], 0.3, 0.5, 0.1),
    Bar([0.2, 0.0], 1.2, 0.03, 2.0),
]


def _items(robot):
    return [
        FootNonOverlap(),
        ObstacleAvoidance(OBSTACLES),
        ComInSupportPolygon(),
        FeetOnFootprints(),
        FramePositionTask(robot.hand_frames["right"], [2.0, 0.0, 0.5]),
        GazeTask(robot.camera_frame, [2.0, 0.3, 0.2]),
        FacingTask([2.5, 0.4], [0.0, 0.0]),
        ReachTask([2.5, 0.4], [0.45, -0.25]),
        PostureTask(robot.reference_posture, np.arange(6, robot.model.nv)),
        FootprintPoseTask(3, [1.0, 0.2, 0.3]),
        StanceGoalTask([1.0, 0.1, 0.2]),
        StepPreferenceTask(0.17),
    ]


def _value(item, kin):
    return item.compute_value(kin) if isinstance(item, Constraint) else item.compute_error(kin)


@pytest.fixture(scope="module")
def perturbed(robot):
    rng = np.random.default_rng(7)
    stance = Stance(np.array([0.1, 0.085, 0.1]), np.array([0.1, -0.085, 0.1]))
    augmented = AugmentedRobot(robot, stance, "right")
    config = augmented.neutral_configuration(4)
    config.steps += rng.normal(scale=0.05, size=config.steps.shape)
    config.q_robot = pin.integrate(
        robot.model, config.q_robot, rng.normal(scale=0.1, size=robot.model.nv)
    )
    return augmented, config


@pytest.mark.parametrize("robot_free", [True, False], ids=["posture_free", "posture_frozen"])
def test_jacobians_match_finite_differences(robot, perturbed, robot_free):
    augmented, config = perturbed
    h = 1e-6
    for item in _items(robot):
        if not robot_free and isinstance(
            item, (FeetOnFootprints, PostureTask, ComInSupportPolygon)
        ):
            continue  # their values do not depend on the step variables alone
        kin = augmented.evaluate(config, robot_free=robot_free)
        J = item.compute_jacobian(kin)
        value = _value(item, kin)
        assert J.shape == (value.shape[0], kin.nv), item.name
        J_fd = np.zeros_like(J)
        for j in range(kin.nv):
            dv = np.zeros(kin.nv)
            dv[j] = h
            plus = _value(item, augmented.evaluate(augmented.integrate(config, dv), robot_free))
            minus = _value(item, augmented.evaluate(augmented.integrate(config, -dv), robot_free))
            J_fd[:, j] = (plus - minus) / (2.0 * h)
        assert np.allclose(J, J_fd, atol=1e-6), (item.name, np.abs(J - J_fd).max())


def test_rigid_stance_jacobians_match_finite_differences(robot, perturbed):
    augmented, config = perturbed
    frames = {
        n: (p, R) for n, (p, R, _) in augmented._robot_kinematics(config.q_robot)["frames"].items()
    }
    pose = np.array([1.2, -0.3, 0.4])
    for item in [
        FramePositionTask(robot.hand_frames["right"], [2.0, 0.0, 0.5]),
        GazeTask(robot.camera_frame, [2.0, 0.3, 0.2]),
        FacingTask([2.5, 0.4], [0, 0]),
    ]:
        J = item.compute_jacobian(RigidStanceKinematics(pose, frames, 0.0))
        J_fd = np.column_stack(
            [
                (
                    item.compute_error(RigidStanceKinematics(pose + 1e-6 * e, frames, 0.0))
                    - item.compute_error(RigidStanceKinematics(pose - 1e-6 * e, frames, 0.0))
                )
                / 2e-6
                for e in np.eye(3)
            ]
        )
        assert np.allclose(J, J_fd, atol=1e-6), item.name


def _inside_rectangle(points, center, yaw, length, width):
    local = (points - center) @ rotation_2d(yaw)
    return (np.abs(local[:, 0]) <= 0.5 * length) & (np.abs(local[:, 1]) <= 0.5 * width)


def _sole_samples(pose, n=60):
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(-0.5, 0.5, n))
    local = np.column_stack([u.ravel() * TALOS_FOOT.length, v.ravel() * TALOS_FOOT.width])
    return pose[:2] + local @ rotation_2d(pose[2]).T


def test_circle_clearance_is_the_distance_to_the_sole_minus_radius_and_buffer():
    rng = np.random.default_rng(3)
    circle = CircleObstacle([0.0, 0.0], 0.08, buffer=0.02)
    for _ in range(30):
        pose = np.array([*rng.uniform(-0.4, 0.4, 2), rng.uniform(-np.pi, np.pi)])
        value = sole_clearance(pose, TALOS_FOOT, circle)[0][0]
        samples = _sole_samples(pose, 120)
        distance = np.min(np.linalg.norm(samples - circle.center, axis=1))
        if distance > 1e-3:  # outside: the clearance is the Euclidean distance
            assert value == pytest.approx(distance - 0.1, abs=3e-3)
        else:
            assert value < -0.1 + 1e-9


def test_rectangle_clearance_non_negative_means_no_contact_within_the_buffer():
    rng = np.random.default_rng(4)
    region = RectangleObstacle([0.0, 0.0], 0.3, 0.6, 0.1, buffer=0.03)
    grown_contacts = 0
    for _ in range(200):
        pose = np.array([*rng.uniform(-0.5, 0.5, 2), rng.uniform(-np.pi, np.pi)])
        value = np.min(sole_clearance(pose, TALOS_FOOT, region)[0])
        samples = _sole_samples(pose, 40)
        # Brute force: does the sole come within the buffer of the rectangle?
        local = (samples - region.center) @ rotation_2d(region.yaw)
        gap = np.hypot(
            np.maximum(np.abs(local[:, 0]) - 0.3, 0.0), np.maximum(np.abs(local[:, 1]) - 0.05, 0.0)
        )
        if value >= 0.0:
            assert np.min(gap) >= 0.03 - 1e-9
        grown_contacts += int(np.min(gap) < 0.03)
    assert 20 < grown_contacts < 180  # the sample covered both cases


def test_non_overlap_rows_non_negative_means_successive_soles_are_disjoint(stance):
    rng = np.random.default_rng(5)
    augmented = AugmentedRobot(None, stance, "right", TALOS_FOOT)
    constraint = FootNonOverlap(margin=0.0)
    satisfied = 0
    for _ in range(300):
        config = augmented.neutral_configuration(1)
        config.steps[0] = rng.uniform([-0.3, -0.3, -0.6], [0.3, 0.0, 0.6])
        kin = augmented.evaluate(config)
        if np.min(constraint.compute_value(kin)) < 0.0:
            continue
        satisfied += 1
        a, b = kin.footprint(0), kin.footprint(1)
        inside = _inside_rectangle(
            _sole_samples(b), a[:2], a[2], TALOS_FOOT.length, TALOS_FOOT.width
        )
        assert not np.any(inside)
    assert satisfied > 30


def test_step_bounds_mirror_for_the_right_foot():
    b = StepBounds()
    lo_l, hi_l = b.lower_upper(True)
    lo_r, hi_r = b.lower_upper(False)
    assert np.allclose(lo_r, [lo_l[0], -hi_l[1], -hi_l[2]])
    assert np.allclose(hi_r, [hi_l[0], -lo_l[1], -lo_l[2]])
    with pytest.raises(InvalidProblem, match="inconsistent step bounds"):
        StepBounds(min_length=0.3, max_length=0.2)


def test_obstacles_reject_bad_geometry():
    with pytest.raises(InvalidProblem, match="radius > 0"):
        CircleObstacle([0.0, 0.0], -1.0)
    with pytest.raises(InvalidProblem, match="2 finite numbers"):
        Bar([0.0, np.inf], 0.0, 0.02, 1.0)
