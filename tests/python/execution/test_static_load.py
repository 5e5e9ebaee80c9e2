"""The static load (execution/static_load.py): gravity torques with carried objects against a
closed form (a one-joint arm holding a weight) and against finite differences of the potential
energy on the plank plan (TALOS, the right hand carrying the plank), and the joints it judges."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.execution.static_load import (
    Carried,
    judged_joints,
    static_torques,
    step_static_load,
)

GRAVITY = 9.81  # [m/s^2], Pinocchio's default model.gravity


def _one_joint_arm(m: float, L: float) -> tuple[pin.Model, int]:
    """A hinge about y at the origin, a point mass m at (L, 0, 0) of its link, a gripper frame
    at (2L, 0, 0)."""
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelRY(), pin.SE3.Identity(), "hinge")
    model.appendBodyToJoint(
        j, pin.Inertia(m, np.array([L, 0, 0]), np.zeros((3, 3))), pin.SE3.Identity()
    )
    frame = model.addFrame(
        pin.Frame(
            "gripper", j, 0, pin.SE3(np.eye(3), np.array([2 * L, 0, 0])), pin.FrameType.OP_FRAME
        )
    )
    return model, frame


def test_a_one_joint_arm_holding_a_weight_matches_the_closed_form():
    m, L, M, d = 1.3, 0.4, 0.7, 0.1  # link mass, its lever, the object's mass, its CoM offset
    model, frame = _one_joint_arm(m, L)
    data = model.createData()
    for q in np.linspace(-1.2, 1.2, 9):
        qv = np.array([q])
        pin.framesForwardKinematics(model, data, qv)
        X_WO = data.oMf[frame] * pin.SE3(np.eye(3), np.array([d, 0, 0]))
        tau = static_torques(model, data, qv, [(Carried(frame, M, np.zeros(3)), X_WO)])
        # RY turns x towards -z: the masses sit at height -sin q times their levers, so
        # V = -g sin q (m L + M (2L + d)) and the torque that holds them is dV/dq.
        expected = -GRAVITY * np.cos(q) * (m * L + M * (2 * L + d))
        assert abs(tau[0] - expected) < 1e-9, (q, tau[0], expected)


def test_the_plank_plan_torques_are_the_potential_energys_gradient(talos_plank):
    """On the carry steps where the right hand alone holds the plank, each judged joint's
    static torque equals dV/dq_j, V the robot's potential energy plus the plank's (the plank
    moving rigidly with the hand), by central differences."""
    p = talos_plank
    model, rm = p.model, p.robot_map
    data = model.createData()
    frame = model.getFrameId(p.ctx.gripper_frames["talos/right_gripper"])
    mass, com = (lambda i: (float(i.mass), np.array(i.lever)))(
        robots.load_object("plank").model.inertias[1]
    )
    contacts = [c.link for c in robots.semantics("talos").contacts]
    joints = judged_joints(model, contacts)
    names = {model.names[j] for j in joints}
    assert {f"arm_right_{i}_joint" for i in range(1, 8)} <= names
    assert not any(n.startswith("leg_") for n in names)  # loaded by the ground: not judged
    carries = [s for s in p.steps if s.grasps == {"talos/right_gripper": "plank/H1"}]
    assert carries
    checked = 0
    for step in carries:
        for q_plan in step.q[:: max(1, len(step.q) // 3)]:
            q = rm.robot_q(q_plan)
            X_WO = rm.object_pose(q_plan, "plank")
            pin.framesForwardKinematics(model, data, q)
            X_GO = data.oMf[frame].actInv(X_WO)  # the plank rigid in the hand

            def V(qq: np.ndarray, X_GO: pin.SE3 = X_GO) -> float:
                pin.framesForwardKinematics(model, data, qq)
                z = (data.oMf[frame] * X_GO).act(com)[2]
                return float(pin.computePotentialEnergy(model, data, qq)) + mass * GRAVITY * z

            tau = static_torques(model, data, q, [(Carried(frame, mass, com), X_WO)])
            for j in joints:
                dq = np.zeros(model.nv)
                dq[model.joints[j].idx_v] = 1e-6
                fd = (V(pin.integrate(model, q, dq)) - V(pin.integrate(model, q, -dq))) / 2e-6
                assert abs(tau[model.joints[j].idx_v] - fd) < 1e-4, (model.names[j], tau, fd)
                checked += 1
    assert checked > 50


def test_the_plank_plan_reports_the_right_wrist_loaded_by_the_plank(talos_plank):
    """The plank flip's right wrist (arm_right_5_joint, a 3 N m actuator) bears most of its
    limit while the right hand alone carries the plank; without the plank it bears less."""
    p = talos_plank
    contacts = [c.link for c in robots.semantics("talos").contacts]
    carry = next(s for s in p.steps if s.grasps == {"talos/right_gripper": "plank/H1"})
    load = step_static_load(p.model, p.robot_map, carry, p.ctx.gripper_frames, contacts)
    assert load is not None and load.joint.startswith("arm_right_")
    empty = step_static_load(p.model, p.robot_map, carry, {}, contacts)  # no gripper: no plank
    assert empty is not None and empty.ratio < load.ratio
