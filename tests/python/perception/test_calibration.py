"""Calibration: TALOS joint offsets by simultaneous projection (thesis 000 §4.2) and the head
camera mount by hand-eye calibration (thesis 001 §4.3) from detected synthetic images."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from marionette import robots
from marionette.perception import synthetic as syn
from marionette.perception.calibration import (
    CalibrationError,
    JointOffsetProblem,
    calibrate_head_camera,
    calibrate_joint_offsets,
    marker_positions,
    residuals_and_jacobian,
)
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import AprilTagDetector, DetectorConfig, rotation_angle

ARM = tuple(f"arm_right_{i}_joint" for i in range(1, 8))
# Thesis §4.1: ~7 deg on the shoulder joint about the vertical axis, 4 deg on a wrist joint.
SHOULDER, WRIST = "arm_right_1_joint", "arm_right_5_joint"


@pytest.fixture(scope="module")
def talos():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    return model


@pytest.fixture(scope="module")
def problem(talos):
    # MoCap markers: a cluster on the chest, one on the right gripper (§4.2, fig. 4.2). With
    # positions only, the last wrist joint's offset is indistinguishable from turning the
    # gripper marker about that joint's axis: joints 1-6 are calibrated, joint 7's offset is
    # absorbed by p_EM (see test_last_joint_with_positions_only_is_refused).
    return JointOffsetProblem(talos, "torso_2_link", "gripper_right_base_link", ARM[:6])


def random_arm_configurations(model, n: int, rng: np.random.Generator) -> np.ndarray:
    """Half-sitting with the right arm drawn uniformly in the middle 80% of its joint range."""
    q0 = robots.reference_configuration("talos", model)
    Q = np.tile(q0, (n, 1))
    for name in ARM:
        j = model.joints[model.getJointId(name)].idx_q
        lo, hi = model.lowerPositionLimit[j], model.upperPositionLimit[j]
        mid, half = (lo + hi) / 2, 0.4 * (hi - lo)
        Q[:, j] = rng.uniform(mid - half, mid + half, n)
    return Q


def test_jacobian_matches_finite_differences(problem, talos):
    rng = np.random.default_rng(1)
    Q = random_arm_configurations(talos, 4, rng)
    offsets = rng.normal(0, 0.05, 6)
    p_EM, p_BA = np.array([0.03, -0.02, -0.12]), np.array([0.1, 0.0, 0.2])
    measured = rng.normal(0, 0.1, (4, 3))
    _r, J = residuals_and_jacobian(problem, Q, measured, offsets, p_EM, p_BA)
    x = np.concatenate([offsets, p_EM, p_BA])
    eps = 1e-6
    J_fd = np.empty_like(J)
    for c in range(len(x)):
        dx = np.zeros_like(x)
        dx[c] = eps
        plus = residuals_and_jacobian(problem, Q, measured, *np.split(x + dx, [6, 9]))[0]
        minus = residuals_and_jacobian(problem, Q, measured, *np.split(x - dx, [6, 9]))[0]
        J_fd[:, c] = (plus - minus) / (2 * eps)
    np.testing.assert_allclose(J, J_fd, atol=1e-7)


def test_recovers_7deg_shoulder_and_4deg_wrist_offsets(problem, talos):
    rng = np.random.default_rng(2022)
    true = rng.normal(0.0, math.radians(0.2), len(ARM))  # small offsets everywhere...
    true[ARM.index(SHOULDER)] = math.radians(7.0)  # ... and the two of thesis §4.1
    true[ARM.index(WRIST)] = math.radians(4.0)
    p_EM, p_BA = np.array([0.02, 0.03, -0.11]), np.array([0.12, -0.05, 0.25])
    Q = random_arm_configurations(talos, 60, rng)
    # What the MoCap sees (0.5 mm noise, §4.2: 0.6 mm reprojection error over the room),
    # simulated on the full arm, joint 7 included.
    full = JointOffsetProblem(talos, "torso_2_link", "gripper_right_base_link", ARM)
    measured = marker_positions(full, Q, true, p_EM, p_BA) + rng.normal(0, 5e-4, (60, 3))
    result = calibrate_joint_offsets(problem, Q, measured)
    error_deg = np.degrees(np.abs(result.offsets - true[:6]))
    assert error_deg[:5].max() < 0.1, dict(zip(ARM, error_deg.round(3)))
    # Joints 5-7 cross at one point (spherical wrist): from marker positions alone, joint 6's
    # offset shows only through joint 7's +/-40 deg, so it is known to ~0.3 deg here, and the
    # calibration says so.
    assert 0.1 < math.degrees(result.offsets_std[5]) < 0.5
    assert error_deg[5] < 4 * math.degrees(result.offsets_std[5])
    # Joint 7's 0.2 deg offset turns the marker about joint 7's axis: p_EM absorbs it, as
    # X_BE(q)^-1 X_BE(q + delta_7) p_EM (the same for every q).
    data = talos.createData()
    q = Q[0].copy()
    X_BE = []
    for d7 in (0.0, true[6]):
        q[talos.joints[talos.getJointId(ARM[6])].idx_q] = (
            Q[0][talos.joints[talos.getJointId(ARM[6])].idx_q] + d7
        )
        pin.framesForwardKinematics(talos, data, q)
        X_BE.append(data.oMf[talos.getFrameId("gripper_right_base_link")])
    p_EM_absorbed = (X_BE[0].inverse() * X_BE[1]).act(p_EM)
    assert np.linalg.norm(result.p_EM - p_EM_absorbed) < 3e-3  # correlated with joint 6's
    assert np.linalg.norm(result.p_BA - p_BA) < 1e-3
    assert result.rms_residual < 1e-3
    # The reported uncertainty is consistent with the actual error.
    assert np.all(np.abs(result.offsets - true[:6]) < 5 * result.offsets_std + 1e-4)


def test_last_joint_with_positions_only_is_refused(talos):
    full = JointOffsetProblem(talos, "torso_2_link", "gripper_right_base_link", ARM)
    rng = np.random.default_rng(5)
    Q = random_arm_configurations(talos, 30, rng)
    measured = marker_positions(full, Q, np.zeros(7), np.array([0.02, 0.03, -0.11]), np.zeros(3))
    with pytest.raises(CalibrationError, match="offset arm_right_7_joint"):
        calibrate_joint_offsets(full, Q, measured)


def test_unobservable_configurations_are_refused(problem, talos):
    Q = np.tile(robots.reference_configuration("talos", talos), (10, 1))  # never moves
    measured = marker_positions(problem, Q, np.zeros(6), np.zeros(3), np.zeros(3))
    with pytest.raises(CalibrationError, match="not observable"):
        calibrate_joint_offsets(problem, Q, measured)
    with pytest.raises(CalibrationError, match="9 equations for 12 unknowns"):
        calibrate_joint_offsets(problem, Q[:3], measured[:3])
    with pytest.raises(CalibrationError, match="not a 1-dof joint"):
        JointOffsetProblem(talos, "torso_2_link", "gripper_right_base_link", ("root_joint",))


def test_head_camera_mount_within_2mm_and_0p2deg_from_detected_tags(talos):
    """Thesis 001 §4.3 with an AprilTag instead of a chessboard: the tag is held in the right
    gripper, the head camera sees it in 30 hand/head configurations, and the mount X_GC is
    recovered from the kinematic X_GH_i and the detected X_CT_i (Tsai-Lenz)."""
    data = talos.createData()
    pin.framesForwardKinematics(talos, data, pin.neutral(talos))
    X_WG = data.oMf[talos.getFrameId("head_2_link")]
    X_WC_cad = data.oMf[talos.getFrameId("rgbd_optical_frame")]
    # The real mount differs from the CAD by 8 mm and 1.5 deg.
    X_GC = (
        X_WG.inverse()
        * X_WC_cad
        * pin.SE3(pin.exp3(np.radians([1.0, -1.0, 0.5])), np.array([0.005, -0.004, 0.005]))
    )
    X_HT = pin.SE3(pin.exp3(np.array([0.3, 0.2, 0.1])), np.array([0.02, 0.0, 0.12]))
    K = CameraIntrinsics.from_fovy(640, 480, 45.0)
    detector = AprilTagDetector(DetectorConfig(tag_sizes={21: 0.08}))
    rng = np.random.default_rng(3)
    X_GH, X_CT = [], []
    for i in range(30):
        p = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), rng.uniform(0.45, 0.8)])
        X_true = syn.look_at(
            p,
            tilt_deg=rng.uniform(15, 40),
            tilt_axis=(math.cos(i), math.sin(i), 0.0),
            roll_deg=rng.uniform(-90, 90),
        )
        frame = syn.render(
            K,
            [syn.tag_quad(21, 0.08, X_true)],
            background_depth=2.0,
            noise_std=2.0,
            depth_noise_std=0.0015,
            rng=rng,
            supersample=3,
        )
        (d,) = detector.detect(frame.gray, K, depth=frame.depth)
        X_CT.append(d.X_CT)
        X_GH.append(X_GC * X_true * X_HT.inverse())  # what the kinematics report
    result = calibrate_head_camera(X_GH, X_CT)
    assert np.linalg.norm(result.X_EC.translation - X_GC.translation) < 2e-3
    assert math.degrees(rotation_angle(result.X_EC.rotation, X_GC.rotation)) < 0.2
    # The CAD mount is clearly worse: the calibration measured something.
    cad = X_WG.inverse() * X_WC_cad
    assert np.linalg.norm(cad.translation - X_GC.translation) > 5e-3
    assert np.linalg.norm(result.X_RT.translation - X_HT.translation) < 3e-3


def test_calibrate_command_prints_the_hand_eye_result_as_json(tmp_path, capfd):
    import json

    from marionette.cli import main

    rng = np.random.default_rng(4)
    X_EC = pin.SE3(pin.exp3(np.array([0.2, -0.1, 0.3])), np.array([0.05, 0.02, 0.1]))
    X_RT = pin.SE3(pin.exp3(np.array([0.0, 0.3, 0.0])), np.array([0.7, 0.1, 0.2]))
    X_RE = [
        pin.SE3(pin.exp3(rng.uniform(-0.6, 0.6, 3)), rng.uniform(-0.2, 0.2, 3)) for _ in range(8)
    ]
    X_CT = [X_EC.inverse() * X.inverse() * X_RT for X in X_RE]
    path = tmp_path / "pairs.json"
    path.write_text(
        json.dumps(
            {
                "X_RE": [X.homogeneous.tolist() for X in X_RE],
                "X_CT": [X.homogeneous.tolist() for X in X_CT],
            }
        )
    )
    assert main(["calibrate", "hand-eye", str(path)]) == 0
    captured = capfd.readouterr()  # file-descriptor level: what ViSP prints from C++ too
    result = json.loads(captured.out)  # stdout is the JSON alone
    assert "Mean residual" in captured.err  # ViSP's own report went to stderr
    np.testing.assert_allclose(result["X_EC"], X_EC.homogeneous, atol=1e-6)


def test_recovers_offsets_from_a_wrist_tag_seen_by_the_head_camera(talos):
    """§4.2 with the robot's own camera instead of a MoCap: a 5 cm tag on the right wrist,
    detected (with depth) in synthetic head-camera images of 30 arm configurations around one
    where the hand is in front of the face; the camera frame is the base frame."""
    from marionette import _visp

    data = talos.createData()

    def idx(name):
        return talos.joints[talos.getJointId(name)].idx_q

    iq = np.array([idx(n) for n in ARM])
    q_n = robots.reference_configuration("talos", talos)
    q_n[idx("head_1_joint")], q_n[idx("head_2_joint")] = 0.5, -0.3  # looking down, right
    q_n[iq] = [1.02, -0.73, -0.72, -1.74, 0.0, 0.0, 0.1]  # hand 45 cm in front of the camera
    E, C = talos.getFrameId("arm_right_7_link"), talos.getFrameId("rgbd_optical_frame")

    def fk(q):
        pin.framesForwardKinematics(talos, data, q)
        return pin.SE3(data.oMf[E]), pin.SE3(data.oMf[C])

    X_WE, X_WC = fk(q_n)
    X_ET = X_WE.inverse() * X_WC * syn.look_at([0.0, 0.0, 0.45], tilt_deg=20, roll_deg=10)
    K = CameraIntrinsics.from_fovy(640, 480, 60.0)
    # Full resolution, as the product's calibration detects (arm_calibration.py).
    detector = AprilTagDetector(DetectorConfig(tag_sizes={40: 0.05}, quad_decimate=1.0))
    rng = np.random.default_rng(11)
    true = rng.normal(0, math.radians(0.2), 7)
    true[ARM.index(SHOULDER)], true[ARM.index(WRIST)] = math.radians(7.0), math.radians(4.0)
    lo, hi = talos.lowerPositionLimit[iq], talos.upperPositionLimit[iq]
    spread = np.radians([15, 15, 15, 15, 40, 40, 30])
    Q, measured = [], []
    while len(Q) < 30:
        q = q_n.copy()
        q[iq] = np.clip(q[iq] + rng.uniform(-1, 1, 7) * spread, lo, hi)
        q_true = q.copy()
        q_true[iq] += true
        X_WE, X_WC = fk(q_true)
        X_CT = X_WC.inverse() * X_WE * X_ET
        corners = (X_CT.homogeneous @ np.c_[_visp.tag_corners(0.05), np.ones(4)].T).T[:, :3]
        sight = X_CT.translation / np.linalg.norm(X_CT.translation)
        if corners[:, 2].min() < 0.25 or -X_CT.rotation[:, 2] @ sight < 0.5:
            continue  # too close, or seen at more than 60 deg
        uv = K.project(corners)
        if uv.min() < 20 or uv[:, 0].max() > 620 or uv[:, 1].max() > 460:
            continue  # out of the image
        frame = syn.render(
            K,
            [syn.tag_quad(40, 0.05, X_CT)],
            background_depth=1.5,
            noise_std=2.0,
            depth_noise_std=0.0015,
            rng=rng,
            supersample=3,
        )
        detections = detector.detect(frame.gray, K, depth=frame.depth)
        if detections:
            Q.append(q)
            measured.append(detections[0].X_CT.translation)
    problem = JointOffsetProblem(talos, "rgbd_optical_frame", "arm_right_7_link", ARM[:6])
    result = calibrate_joint_offsets(problem, np.array(Q), np.array(measured))
    error_deg = np.degrees(np.abs(result.offsets - true[:6]))
    assert error_deg.max() < 0.1, dict(zip(ARM, error_deg.round(3)))
    assert np.linalg.norm(result.p_BA) < 1e-3  # measured in the camera frame itself


# ---- joint offsets from marker poses (the wrist ring seen by the head camera) -----------------

LEFT_ARM = tuple(f"arm_left_{i}_joint" for i in range(1, 8))


def wrist_poses(model, Q, correction, frame="arm_left_7_link"):
    """X_BE (torso_2_link <- frame) of arms whose true angles are the readings + correction."""
    data = model.createData()
    iq = [model.joints[model.getJointId(j)].idx_q for j in LEFT_ARM]
    out = []
    for q in Q:
        q = q.copy()
        q[iq] += correction
        pin.framesForwardKinematics(model, data, q)
        out.append(
            data.oMf[model.getFrameId("torso_2_link")].inverse() * data.oMf[model.getFrameId(frame)]
        )
    return out


def left_arm_configurations(model, n, rng):
    q0 = robots.reference_configuration("talos", model)
    Q = np.tile(q0, (n, 1))
    for name in LEFT_ARM:
        j = model.joints[model.getJointId(name)].idx_q
        lo, hi = model.lowerPositionLimit[j], model.upperPositionLimit[j]
        Q[:, j] = rng.uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo), n)
    return Q


def test_pose_residual_jacobian_matches_finite_differences(talos):
    from marionette.perception.calibration import pose_residuals_and_jacobian

    rng = np.random.default_rng(3)
    problem = JointOffsetProblem(talos, "torso_2_link", "arm_left_7_link", LEFT_ARM)
    Q = left_arm_configurations(talos, 3, rng)
    measured = [X * pin.exp6(rng.normal(0, 0.05, 6)) for X in wrist_poses(talos, Q, np.zeros(7))]
    x = rng.normal(0, 0.05, 7)
    _r, J = pose_residuals_and_jacobian(problem, Q, measured, x, rotation_weight=0.1)
    J_fd = np.empty_like(J)
    for c in range(7):
        dx = np.zeros(7)
        dx[c] = 1e-6
        J_fd[:, c] = (
            pose_residuals_and_jacobian(problem, Q, measured, x + dx, 0.1)[0]
            - pose_residuals_and_jacobian(problem, Q, measured, x - dx, 0.1)[0]
        ) / 2e-6
    np.testing.assert_allclose(J, J_fd, atol=1e-7)


def test_every_arm_joint_from_wrist_poses_with_camera_noise(talos):
    """With the marker's full pose, joint 7 is observable too (contrast with positions only)."""
    from marionette.perception.calibration import calibrate_joint_offsets_from_poses

    rng = np.random.default_rng(4)
    true = rng.normal(0.0, math.radians(0.2), 7)
    true[0], true[6] = math.radians(-7.0), math.radians(-4.0)
    Q = left_arm_configurations(talos, 10, rng)
    # the ring's pose from the head camera: ~1 mm and ~0.3 deg per view
    measured = [
        X * pin.exp6(np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, math.radians(0.3), 3)])
        for X in wrist_poses(talos, Q, true)
    ]
    measured[3] = measured[3] * pin.exp6(np.r_[0.03, 0.0, 0.0, 0.0, 0.3, 0.0])  # one wrong pose
    problem = JointOffsetProblem(talos, "torso_2_link", "arm_left_7_link", LEFT_ARM)
    result = calibrate_joint_offsets_from_poses(problem, Q, measured)
    error_deg = np.degrees(np.abs(result.offsets - true))
    assert error_deg.max() < 0.25, dict(zip(LEFT_ARM, error_deg.round(3)))
    assert result.outliers == (3,)  # the wrong pose is left out, the rest fit
    assert np.median(result.position_residuals) < 3e-3
    with pytest.raises(CalibrationError, match="not observable"):
        calibrate_joint_offsets_from_poses(problem, np.tile(Q[0], (3, 1)), [measured[0]] * 3)
    with pytest.raises(CalibrationError, match="finite"):
        calibrate_joint_offsets_from_poses(problem, Q[:2] * np.nan, measured[:2])
