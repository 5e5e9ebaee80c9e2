"""``marionette perceive``: frame decoding and validation, robot-state kinematics, and the
process end to end over LCM (TALOS kinematics place the camera; synthetic frames of the plank)."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette import channels, robots
from marionette.lcm_bus import LcmBus, MessageLog
from marionette.perception import synthetic as syn
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import rotation_angle
from marionette.perception.kinematics import CameraKinematics, StateError, configuration_from_state
from marionette.perception.node import FrameError, camera_image_arrays, decode_frame
from marionette.perception.objects import load_tagged_bodies
from tests_support import wait_for_line

K = CameraIntrinsics.from_fovy(640, 480, 45.0)
PLANK_YAML = marionette.MODELS_DIR / "objects" / "plank.yaml"


def camera_message(
    frame: syn.SyntheticFrame | None,
    utime: int,
    K: CameraIntrinsics = K,
    X_WC: pin.SE3 | None = None,
    depth_scale: float = 0.001,
):
    from marionette import lcmt_camera_image

    msg = lcmt_camera_image()
    msg.utime = utime
    msg.camera_name = "head"
    msg.frame_name = "rgbd_optical_frame"
    msg.width, msg.height = K.width, K.height
    msg.fx, msg.fy, msg.cx, msg.cy = K.fx, K.fy, K.cx, K.cy
    msg.depth_scale = depth_scale
    X = X_WC if X_WC is not None else pin.SE3.Identity()
    q = pin.Quaternion(X.rotation)
    msg.camera_position = list(X.translation)
    msg.camera_quaternion = [q.w, q.x, q.y, q.z]
    if frame is not None:
        msg.rgb = frame.rgb.tobytes()
        msg.num_rgb = len(msg.rgb)
        mm = np.rint(frame.depth / depth_scale).astype(np.int16)
        msg.depth = mm.ravel().tolist()
        msg.num_depth = len(msg.depth)
    return msg


def state_message(model: pin.Model, q: np.ndarray, utime: int):
    from marionette import lcmt_robot_state

    msg = lcmt_robot_state()
    msg.utime = utime
    msg.robot_name = model.name
    names = [model.names[j] for j in range(2, model.njoints)][::-1]  # any order
    msg.joint_name = names
    msg.joint_position = [float(q[model.joints[model.getJointId(n)].idx_q]) for n in names]
    msg.joint_velocity = [0.0] * len(names)
    msg.joint_effort = [0.0] * len(names)
    msg.num_joints = len(names)
    msg.base_position = list(q[:3])
    msg.base_quaternion = [q[6], q[3], q[4], q[5]]
    msg.base_linear_velocity = [0.0] * 3
    msg.base_angular_velocity = [0.0] * 3
    return msg


def test_frames_decode_to_luma_and_metric_depth():
    frame = syn.render(K, [], background=100.0, background_depth=1.234)
    decoded = decode_frame(camera_message(frame, 7))
    assert decoded.utime == 7 and decoded.intrinsics == K
    assert decoded.gray.shape == (480, 640) and np.all(decoded.gray == 100)  # weights sum to 256
    np.testing.assert_allclose(decoded.depth, 1.234, atol=1e-6)
    red = camera_message(frame, 8)
    red.rgb = np.tile(np.array([255, 0, 0], np.uint8), 640 * 480).tobytes()
    assert np.all(decode_frame(red).gray == 76)  # BT.601: 0.299 * 255
    assert decoded.X_WC_message is not None


@pytest.mark.parametrize("seed", range(4))
def test_the_cpp_decoder_gives_what_lcm_gens_python_decoder_gives(seed):
    """``camera_image_arrays`` (lcm-gen's C++ decoder, arrays as numpy) against lcm-gen's Python
    decoder on frames of random sizes, with and without depth, every int16 sign; the decoded
    frames are the same to the bit; bytes that are not a frame raise."""
    from marionette import lcmt_camera_image

    rng = np.random.default_rng(seed)
    Ks = CameraIntrinsics.from_fovy(int(rng.integers(1, 90)), int(rng.integers(1, 70)), 50.0)
    msg = camera_message(None, int(rng.integers(0, 1 << 40)), Ks, pin.SE3.Random())
    msg.rgb = rng.integers(0, 256, Ks.width * Ks.height * 3, dtype=np.uint8).tobytes()
    msg.num_rgb = len(msg.rgb)
    if seed % 2:
        msg.depth = rng.integers(-(1 << 15), 1 << 15, Ks.width * Ks.height).tolist()
        msg.num_depth = len(msg.depth)
    data = msg.encode()
    ours, theirs = camera_image_arrays(data), lcmt_camera_image.decode(data)
    for name in lcmt_camera_image.__slots__:
        a, b = getattr(ours, name), getattr(theirs, name)
        if name == "rgb":
            assert np.asarray(a).tobytes() == b
        elif isinstance(b, list | tuple):
            assert np.asarray(a).tolist() == list(b), name
        else:
            assert a == b, name
    f_ours, f_theirs = decode_frame(ours), decode_frame(theirs)
    assert np.array_equal(f_ours.gray, f_theirs.gray)
    assert (f_ours.depth is None) == (f_theirs.depth is None)
    if f_ours.depth is not None:
        assert np.array_equal(f_ours.depth, f_theirs.depth)
    with pytest.raises(ValueError, match="not an lcmt_camera_image"):
        camera_image_arrays(data[:-1])


@pytest.mark.parametrize(
    "field, value, reason",
    [
        ("width", 0, "bad_size"),
        ("fx", float("nan"), "bad_intrinsics"),
        ("fy", -1.0, "bad_intrinsics"),
        ("rgb", b"\x00" * 10, "rgb_size"),
        ("depth", [0] * 10, "depth_size"),
        ("depth_scale", 0.0, "depth_scale"),
    ],
)
def test_malformed_frames_are_rejected_with_a_reason(field, value, reason):
    msg = camera_message(syn.render(K, []), 1)
    setattr(msg, field, value)
    if field == "rgb":
        msg.num_rgb = len(value)
    if field == "depth":
        msg.num_depth = len(value)
    with pytest.raises(FrameError) as info:
        decode_frame(msg)
    assert info.value.reason == reason


def test_robot_state_gives_the_configuration_and_the_camera_pose():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    q = robots.reference_configuration("talos", model)
    q[:7] = [0.3, -0.2, 1.02, *pin.Quaternion(pin.rpy.rpyToMatrix(0, 0, 0.7)).coeffs()]
    q[model.joints[model.getJointId("head_1_joint")].idx_q] = 0.2
    np.testing.assert_allclose(configuration_from_state(model, state_message(model, q, 5)), q)
    kin = CameraKinematics(model, "rgbd_optical_frame")
    assert kin.camera_pose(5) is None
    kin.add_state(state_message(model, q, 1000))
    q2 = q.copy()
    q2[model.joints[model.getJointId("head_1_joint")].idx_q] = -0.2
    kin.add_state(state_message(model, q2, 2000))
    X_WC, t = kin.camera_pose(1200)  # the state nearest the image
    assert t == 1000
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    assert np.allclose(
        X_WC.homogeneous, data.oMf[model.getFrameId("rgbd_optical_frame")].homogeneous
    )
    bad = state_message(model, q, 3000)
    bad.joint_name = bad.joint_name[1:]
    bad.joint_position = bad.joint_position[1:]
    bad.num_joints -= 1
    with pytest.raises(StateError, match="lacks joints"):
        kin.add_state(bad)


@pytest.mark.slow
def test_perceive_publishes_detections_and_world_poses_over_lcm(lcm_url, lcm_env, tmp_path):
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    q = robots.reference_configuration("talos", model)
    q[:7] = [0.5, 0.2, 1.02, *pin.Quaternion(pin.rpy.rpyToMatrix(0, 0, 0.4)).coeffs()]
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    X_WC = pin.SE3(data.oMf[model.getFrameId("rgbd_optical_frame")])
    # The plank 0.8 m in front of the camera, its tags facing it at 40 deg.
    X_CB = pin.SE3(pin.rpy.rpyToMatrix(np.radians(140), 0.0, 0.3), np.array([0.05, 0.05, 0.8]))
    X_WB = X_WC * X_CB
    (plank,) = load_tagged_bodies([PLANK_YAML])
    quads = [syn.tag_quad(t.tag_id, t.size, X_CB * t.X_BT) for t in plank.tags]
    frame = syn.render(K, quads, background_depth=2.0, noise_std=2.0, depth_noise_std=0.002)

    cmd = [
        sys.executable,
        "-m",
        "marionette.cli",
        "perceive",
        "--robot",
        "talos",
        "--objects",
        str(PLANK_YAML),
        "--max-frames",
        "3",
        "--duration",
        "60",
        "--stats-period",
        "100",
    ]
    proc = subprocess.Popen(
        cmd, env=lcm_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        assert wait_for_line(proc.stdout, "listening on CAMERA_HEAD", 60.0), (
            "perceive did not start"
        )
        with LcmBus(lcm_url) as bus:
            from marionette import lcmt_apriltag_detections, lcmt_object_poses

            objects = MessageLog(bus, channels.OBJECT_POSES, lcmt_object_poses)
            tags = MessageLog(bus, channels.APRILTAG_DETECTIONS, lcmt_apriltag_detections)
            bus.start()
            bad = camera_message(frame, 1)
            bad.fx = float("nan")
            for i in range(40):
                bus.publish(channels.ROBOT_STATE, state_message(model, q, 1_000_000 + i))
                bus.publish(
                    channels.CAMERA_HEAD, bad if i == 0 else camera_message(frame, 1_000_000 + i)
                )
                if objects.wait_for(lambda m: len(m) >= 3, 0.3):
                    break
            assert len(objects.messages) >= 3, "no object poses published"
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    msg = objects.messages[-1]
    (pose,) = [o for o in msg.objects if o.object_name == "plank"]
    assert sorted(pose.tag_id) == [10, 11]
    p_W = np.array(pose.position_world)
    w, x, y, z = pose.quaternion_world
    assert np.linalg.norm(p_W - X_WB.translation) < 5e-3
    assert math.degrees(rotation_angle(X_WB.rotation, pin.Quaternion(w, x, y, z).matrix())) < 1.0
    assert msg.latency_us > 0.0
    (det,) = [d for d in tags.messages[-1].detections if d.id == 10]
    assert det.resolved_by in ("image", "depth") and det.tag_size == pytest.approx(0.06)
    assert '"bad_intrinsics": 1' in out  # the malformed frame was counted, not fatal


@pytest.mark.parametrize("bound, published", [(math.inf, True), (0.01, True), (1e-5, False)])
def test_a_pose_less_precise_than_the_bound_is_not_published_and_is_counted(bound, published):
    """``max_position_sigma``: the plank seen 1 m away by its two top tags is known to ~1 mm;
    under a 10 µm bound its pose is left out of OBJECT_POSES (the detections still go out) and
    counted as imprecise."""
    from marionette.perception.node import PerceptionConfig, PerceptionNode

    (plank,) = load_tagged_bodies([PLANK_YAML])
    X_CB = pin.SE3(pin.rpy.rpyToMatrix(np.radians(140), 0.0, np.radians(20)), np.array([0, 0, 1.0]))
    quads = [syn.tag_quad(t.tag_id, t.size, X_CB * t.X_BT) for t in plank.tags]
    frame = syn.render(K, quads, background_depth=2.0)
    node = PerceptionNode(
        PerceptionConfig([plank], camera_pose_source="message", max_position_sigma=bound)
    )
    detections, poses = node.process(camera_message(frame, 1000), 0.0)
    assert detections.num_detections == 2
    assert poses.num_objects == (1 if published else 0)
    assert node.counters["imprecise_poses"] == (0 if published else 1)


@pytest.mark.parametrize("margin_deg, published", [(2.0, True), (-2.0, False)])
def test_a_resting_body_estimated_tilted_beyond_the_bound_is_not_published(margin_deg, published):
    """``max_tilt_deg``: a body declared resting with an axis up (``up_axes``) whose estimate
    tilts that axis from the world's z by more than the bound is left out of OBJECT_POSES and
    counted; the tilt is that of the rendered pose (computed here), the bound 2 degrees either
    side of it."""
    from marionette.perception.node import PerceptionConfig, PerceptionNode

    (plank,) = load_tagged_bodies([PLANK_YAML])
    X_CB = pin.SE3(pin.rpy.rpyToMatrix(np.radians(140), 0.0, np.radians(20)), np.array([0, 0, 1.0]))
    up_B = np.array([0.0, 0.0, 1.0])
    X_WC = pin.SE3(pin.rpy.rpyToMatrix(np.radians(-130), 0.0, 0.0), np.zeros(3))
    tilt = np.degrees(np.arccos((X_WC.rotation @ X_CB.rotation @ up_B)[2]))
    assert 5.0 < tilt < 60.0
    quads = [syn.tag_quad(t.tag_id, t.size, X_CB * t.X_BT) for t in plank.tags]
    frame = syn.render(K, quads, background_depth=2.0)
    node = PerceptionNode(
        PerceptionConfig(
            [plank],
            camera_pose_source="message",
            up_axes={"plank": up_B},
            max_tilt_deg=tilt + margin_deg,
        )
    )
    _, poses = node.process(camera_message(frame, 1000, X_WC=X_WC), 0.0)
    assert poses.num_objects == (1 if published else 0)
    assert node.counters["tilted_poses"] == (0 if published else 1)
