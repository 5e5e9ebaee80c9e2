"""PBVS references (thesis 000 eq. 5.1-5.3, §5.2.3) on TALOS with miscalibrated joints."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from marionette import robots
from marionette.perception.detector import rotation_angle
from marionette.perception.pbvs import (
    PbvsReference,
    VisualMeasurement,
    activation,
    se3_error,
    task_reference_message,
    visual_error,
    visual_reference,
)

ARM = [f"arm_right_{i}_joint" for i in range(1, 8)]
GRIPPER, CAMERA = "gripper_right_base_link", "rgbd_optical_frame"


def random_se3(rng) -> pin.SE3:
    return pin.SE3(pin.exp3(rng.normal(0, 1, 3)), rng.normal(0, 0.5, 3))


def test_error_is_the_twist_that_moves_t1_onto_t2_in_unit_time():
    rng = np.random.default_rng(0)
    T1 = random_se3(rng)
    assert np.allclose(se3_error(T1, T1), 0.0)
    xi = np.array([0.1, -0.2, 0.05, 0.3, 0.1, -0.2])
    assert np.allclose(se3_error(T1, T1 * pin.exp6(xi)), xi)


def test_visual_reference_gives_the_measured_displacement_and_ignores_the_camera_pose():
    rng = np.random.default_rng(1)
    g_fk, g_true, H, X_HG = (random_se3(rng) for _ in range(4))
    for X_WC in (random_se3(rng), random_se3(rng)):  # wherever the camera really is
        X_CG, X_CH = X_WC.inverse() * g_true, X_WC.inverse() * H
        T2 = visual_reference(g_fk, X_CG, X_CH, X_HG)
        # eq. 5.3: e(g1, T2) = log((g1^meas)^-1 H1 X_HG)
        assert np.allclose(se3_error(g_fk, T2), visual_error(X_CG, X_CH, X_HG))
        assert np.allclose(se3_error(g_fk, T2), pin.log6(g_true.inverse() * H * X_HG).vector)


class MiscalibratedTalos:
    """TALOS whose right arm joints sit at encoder + offsets (7 deg shoulder, 4 deg wrist)."""

    def __init__(self) -> None:
        self.model, _ = robots.load_pinocchio("talos", with_collision=False)
        self.data = self.model.createData()
        self.iq = np.array([self.model.joints[self.model.getJointId(n)].idx_q for n in ARM])
        self.iv = np.array([self.model.joints[self.model.getJointId(n)].idx_v for n in ARM])
        self.offsets = np.radians([7.0, 0, 0, 0, 4.0, 0, 0])
        self.gripper = self.model.getFrameId(GRIPPER)
        self.camera = self.model.getFrameId(CAMERA)

    def frames(self, q: np.ndarray, true: bool) -> tuple[pin.SE3, pin.SE3]:
        """(gripper, camera) world poses, by the model (encoders) or as they really are."""
        q = q.copy()
        if true:
            q[self.iq] += self.offsets
        pin.framesForwardKinematics(self.model, self.data, q)
        return pin.SE3(self.data.oMf[self.gripper]), pin.SE3(self.data.oMf[self.camera])

    def step_towards(self, q: np.ndarray, reference: pin.SE3, gain: float, dt: float) -> np.ndarray:
        """One kinematic control step of the gripper task on the model: J dq = gain e."""
        pin.computeJointJacobians(self.model, self.data, q)
        pin.framesForwardKinematics(self.model, self.data, q)
        e = se3_error(self.data.oMf[self.gripper], reference)
        J = pin.getFrameJacobian(self.model, self.data, self.gripper, pin.LOCAL)[:, self.iv]
        dq = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), gain * e)
        q = q.copy()
        q[self.iq] += dq * dt
        return q


def test_visual_servoing_reaches_the_handle_despite_joint_offsets():
    robot = MiscalibratedTalos()
    q0 = robots.reference_configuration("talos", robot.model)
    q_goal = q0.copy()
    q_goal[robot.iq] += np.radians([10, -15, 10, -30, 5, 10, 5])
    H, _ = robot.frames(q_goal, true=True)  # a handle the real arm can reach

    # Open loop (chapter 3): the planned reference H, followed on the model.
    q = q0.copy()
    for _ in range(300):
        q = robot.step_towards(q, H, gain=10.0, dt=0.01)
    g_true, _ = robot.frames(q, true=True)
    open_loop_miss = np.linalg.norm(g_true.translation - H.translation)
    assert open_loop_miss > 0.03  # the 7 deg shoulder offset alone moves the hand by cm

    # PBVS: the camera measures gripper and handle every step (0.3 mm / 0.05 deg noise).
    rng = np.random.default_rng(0)
    pbvs = PbvsReference(visual_gain=3.0, planned_gain=10.0, blend_time=0.2)
    q = q0.copy()
    for k in range(600):
        t = 0.01 * k
        g_true, X_WC = robot.frames(q, true=True)
        noise = pin.exp6(np.r_[rng.normal(0, 3e-4, 3), rng.normal(0, 1e-3, 3)])
        measurement = VisualMeasurement(t, X_WC.inverse() * g_true * noise, X_WC.inverse() * H)
        g_fk, _ = robot.frames(q, true=False)
        out = pbvs.update(t, g_fk, H, measurement)
        q = robot.step_towards(q, out.reference, out.gain, 0.01)
    g_true, _ = robot.frames(q, true=True)
    assert out.mode == "visual"
    assert np.linalg.norm(g_true.translation - H.translation) < 1e-3
    assert math.degrees(rotation_angle(g_true.rotation, H.rotation)) < 0.2


def test_loss_of_sight_falls_back_to_the_plan_shifted_by_the_last_offset_without_jumps():
    rng = np.random.default_rng(2)
    P0 = random_se3(rng)
    # The object moved by D after planning: what the camera sees is the plan shifted by D.
    D = pin.SE3(pin.exp3(np.array([0.0, 0.0, 0.2])), np.array([0.05, -0.03, 0.02]))
    pbvs = PbvsReference(visual_gain=1.0, planned_gain=10.0, blend_time=0.3, timeout=0.1)
    dt, outputs = 0.002, []
    for k in range(int(3.0 / dt)):
        t = k * dt
        planned = P0 * pin.SE3(np.eye(3), np.array([0.1 * t, 0.0, 0.0]))  # the planned approach
        g_fk = planned  # the gripper follows perfectly (measured = kinematic here)
        X_WC = random_se3(np.random.default_rng(9))
        seen = 0.5 <= t < 1.5  # visible between 0.5 s and 1.5 s only
        m = (
            VisualMeasurement(t, X_WC.inverse() * g_fk, X_WC.inverse() * D * planned)
            if seen
            else None
        )
        outputs.append((t, planned, pbvs.update(t, g_fk, planned, m)))
    by_time = {round(t, 3): (planned, out) for t, planned, out in outputs}
    assert by_time[0.4][1].mode == "planned"
    assert by_time[1.0][1].mode == "visual"
    planned, out = by_time[1.0]
    assert np.allclose(out.reference.homogeneous, (D * planned).homogeneous, atol=1e-9)
    planned, out = by_time[2.5]
    assert out.mode == "fallback"
    assert np.allclose(out.reference.homogeneous, (D * planned).homogeneous, atol=1e-9)
    # Continuity: consecutive references and gains never jump, even at the switches.
    steps = [
        np.linalg.norm(se3_error(a[2].reference, b[2].reference))
        for a, b in zip(outputs, outputs[1:])
    ]
    assert max(steps) < 0.01  # rad or m per 2 ms; D itself is ~0.2
    gains = np.array([o.gain for _, _, o in outputs])
    assert np.abs(np.diff(gains)).max() < 0.2
    assert gains[0] == 10.0 and by_time[1.2][1].gain == pytest.approx(1.0)


def test_activation_is_a_c2_ramp():
    s = np.linspace(-0.5, 1.5, 2001)
    a = np.array([activation(x) for x in s])
    assert a[0] == 0.0 and a[-1] == 1.0 and np.all(np.diff(a) >= 0)
    assert activation(0.5) == pytest.approx(0.5)
    d1 = np.gradient(a, s)
    assert abs(d1[np.searchsorted(s, 0.0)]) < 1e-2 and abs(d1[np.searchsorted(s, 1.0)]) < 1e-2


def test_task_reference_message_holds_se3_samples():
    T = pin.SE3(pin.exp3(np.array([0.1, 0.2, 0.3])), np.array([1.0, 2.0, 3.0]))
    msg = task_reference_message("right_gripper", 4, 1000, [T, T], dt_us=10000)
    decoded = type(msg).decode(msg.encode())
    assert decoded.num_samples == 2 and decoded.value_size == 7 and decoded.derivative_size == 0
    x, y, z, qw, qx, qy, qz = decoded.value[1]
    assert np.allclose([x, y, z], T.translation)
    assert np.allclose(pin.Quaternion(qw, qx, qy, qz).matrix(), T.rotation)
