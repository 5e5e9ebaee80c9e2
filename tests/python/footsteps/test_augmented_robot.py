"""The augmented robot against Pinocchio: a chain of planar joints and the robot's own FK."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from footsteps_checks import TALOS_FOOT
from marionette.footsteps.augmented_robot import (
    AugmentedConfiguration,
    AugmentedRobot,
    Stance,
    planar_compose,
    planar_relative,
)
from marionette.footsteps.errors import InvalidProblem


def _planar_chain_model(k: int, root: np.ndarray) -> pin.Model:
    """Independent reference: k Pinocchio JointModelPlanar in series under the root footprint."""
    model = pin.Model()
    parent = 0
    placement = pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, root[2]), np.array([root[0], root[1], 0.0]))
    for i in range(k):
        parent = model.addJoint(parent, pin.JointModelPlanar(), placement, f"step_{i + 1}")
        placement = pin.SE3.Identity()
    return model


def test_footprints_match_a_pinocchio_chain_of_planar_joints():
    rng = np.random.default_rng(0)
    stance = Stance(np.array([0.3, 0.5, 0.4]), np.array([0.35, 0.33, 0.4]))
    augmented = AugmentedRobot(None, stance, "left", TALOS_FOOT)
    k = 6
    steps = rng.uniform([-0.1, -0.3, -0.3], [0.25, 0.3, 0.3], size=(k, 3))
    ours = augmented.footprints(steps)
    model = _planar_chain_model(k, augmented.root)
    data = model.createData()
    q = np.concatenate([[s[0], s[1], np.cos(s[2]), np.sin(s[2])] for s in steps])
    pin.forwardKinematics(model, data, q)
    for i in range(1, k + 1):
        M = data.oMi[i]
        assert np.allclose(ours[i + 1, :2], M.translation[:2], atol=1e-12)
        assert np.isclose(
            np.arctan2(M.rotation[1, 0], M.rotation[0, 0]),
            np.arctan2(np.sin(ours[i + 1, 2]), np.cos(ours[i + 1, 2])),
            atol=1e-12,
        )


def test_sides_alternate_from_the_first_moving_foot():
    stance = Stance(np.zeros(3), np.zeros(3))
    augmented = AugmentedRobot(None, stance, "right", TALOS_FOOT)
    # footprints -1..4: right (moves first), left (stance), right, left, right, left
    assert augmented.is_left(4).tolist() == [False, True, False, True, False, True]


def test_robot_frames_are_the_robots_own_fk_placed_on_the_last_footprint(robot, stance):
    rng = np.random.default_rng(1)
    augmented = AugmentedRobot(robot, stance, "right")
    config = augmented.neutral_configuration(3)
    config.steps += rng.normal(scale=0.05, size=config.steps.shape)
    config.q_robot = pin.integrate(
        robot.model, config.q_robot, rng.normal(scale=0.05, size=robot.model.nv)
    )
    kin = augmented.evaluate(config)
    # Reference: Pinocchio FK of the robot whose base is X_W,Pk · X_L,B.
    last = kin.footprint(kin.k)
    X_WL = augmented.footprint_se3(last)
    q = config.q_robot.copy()
    q[:7] = pin.SE3ToXYZQUAT(X_WL * pin.XYZQUATToSE3(q[:7]))
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    for frame in [robot.hand_frames["right"], robot.camera_frame, robot.sole_frames["left"]]:
        p, R = kin.frame_placement(frame)
        M = data.oMf[robot.model.getFrameId(frame)]
        assert np.allclose(p, M.translation, atol=1e-10)
        assert np.allclose(R, M.rotation, atol=1e-10)
    assert np.allclose(kin.com(), pin.centerOfMass(robot.model, data, q), atol=1e-10)


def test_neutral_configuration_stands_on_the_stance(robot, stance):
    augmented = AugmentedRobot(robot, stance, "right")
    kin = augmented.evaluate(augmented.neutral_configuration(0))
    for side, expected in (("left", stance.left), ("right", stance.right)):
        p, _ = kin.frame_placement(robot.sole_frames[side])
        assert np.allclose(p[:2], expected[:2], atol=2e-3)  # half_sitting: soles 0.17 apart
        assert abs(p[2]) < 1e-6


def test_adding_and_removing_a_step_keeps_the_robot_in_place(robot, stance):
    rng = np.random.default_rng(2)
    augmented = AugmentedRobot(robot, stance, "left")
    config = augmented.neutral_configuration(2)
    config.steps += rng.normal(scale=0.05, size=config.steps.shape)
    before = augmented.evaluate(config)
    grown = augmented.add_step(config)
    after = augmented.evaluate(grown)
    assert grown.num_steps == 3
    assert np.allclose(after.footprints[-1], before.footprints[-2], atol=1e-12)  # in place
    for frame in [robot.hand_frames["left"], robot.camera_frame]:
        assert np.allclose(
            after.frame_placement(frame)[0], before.frame_placement(frame)[0], atol=1e-12
        )
    back = augmented.evaluate(augmented.remove_last_step(grown))
    assert np.allclose(
        back.frame_placement(robot.camera_frame)[0],
        before.frame_placement(robot.camera_frame)[0],
        atol=1e-12,
    )


def test_planar_compose_and_relative_are_inverse():
    a, b = np.array([0.4, -0.2, 0.7]), np.array([1.1, 0.3, -0.4])
    assert np.allclose(planar_compose(a, planar_relative(a, b)), b)


def test_bad_inputs_are_rejected_with_a_message(robot):
    with pytest.raises(InvalidProblem, match="first_side"):
        AugmentedRobot(robot, Stance(np.zeros(3), np.zeros(3)), "middle")
    with pytest.raises(InvalidProblem, match=r"stance\.left"):
        Stance(np.array([0.0, np.nan, 0.0]), np.zeros(3))
    augmented = AugmentedRobot(robot, Stance(np.zeros(3), np.zeros(3)), "left")
    with pytest.raises(InvalidProblem, match="q_robot"):
        augmented.evaluate(AugmentedConfiguration(np.zeros((0, 3)), None))
