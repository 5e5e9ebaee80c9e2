"""Detection on images rendered by MuJoCo (marionette._core.sim.RgbdRenderer, EGL): the ground
truth is the simulator's site pose of each tag (tests/data/perception/tag_box_scene.xml)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import AprilTagDetector, DetectorConfig, rotation_angle
from marionette.perception.objects import TaggedBody, TagOnBody, estimate_body_pose

SCENE = marionette.REPO_ROOT / "tests" / "data" / "perception" / "tag_box_scene.xml"
SIZE = 0.08
# The scene's plank: tags 30, 31, 32 on its top, 12 cm apart, 1.1 cm above its centre.
PLANK = TaggedBody(
    "plank",
    "plank",
    tuple(
        TagOnBody(i, SIZE, pin.SE3(np.eye(3), np.array([x, 0.0, 0.011])))
        for i, x in ((30, -0.12), (31, 0.0), (32, 0.12))
    ),
)


@pytest.fixture(scope="module")
def rig():
    from marionette._core import sim

    scene = sim.MjScene(str(SCENE))
    renderer = sim.RgbdRenderer(scene, "head", 640, 480)
    k = renderer.intrinsics
    K = CameraIntrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    detector = AprilTagDetector(
        DetectorConfig(tag_sizes={5: SIZE, 30: SIZE, 31: SIZE, 32: SIZE}, depth_sigma=0.001)
    )
    return scene, renderer, K, detector


def set_free_body(scene, index: int, p: np.ndarray, R: np.ndarray) -> None:
    """Free joint `index` (0 box, 1 plank, 2 occluder): qpos x y z qw qx qy qz."""
    q = scene.qpos.copy()
    quat = pin.Quaternion(R)
    q[7 * index : 7 * index + 7] = [*p, quat.w, quat.x, quat.y, quat.z]
    scene.qpos = q
    scene.forward()


def look(rig):
    scene, renderer, _K, _detector = rig
    rgb, depth = renderer.render(scene)
    gray = np.rint(rgb.mean(axis=2)).astype(np.uint8)
    X_WC = pin.SE3(renderer.camera_pose(scene))
    return gray, depth, X_WC


def truth(scene, X_WC: pin.SE3, name: str) -> pin.SE3:
    return X_WC.inverse() * pin.SE3(scene.site_pose(name))


def errors(X_true: pin.SE3, X: pin.SE3) -> tuple[float, float]:
    return (
        float(np.linalg.norm(X.translation - X_true.translation)),
        math.degrees(rotation_angle(X_true.rotation, X.rotation)),
    )


@pytest.fixture
def reset(rig):
    scene = rig[0]
    set_free_body(scene, 0, np.array([0.15, 0.1, 0.01]), np.eye(3))
    set_free_body(scene, 1, np.array([-0.15, -0.1, 0.01]), np.eye(3))
    set_free_body(scene, 2, np.array([5.0, 5.0, 0.5]), np.eye(3))


def test_depth_is_the_distance_to_the_floor_along_the_optical_axis(rig, reset):
    _gray, depth, X_WC = look(rig)
    assert depth[5, 5] == pytest.approx(1.0, abs=0.01)  # image corner: ray 28 deg off-axis
    assert depth[470, 630] == pytest.approx(1.0, abs=0.01)
    assert np.allclose(X_WC.translation, [0.0, 0.0, 1.0])


@pytest.mark.parametrize("tilt_deg", [30.0, 45.0])
def test_tag_pose_within_5mm_and_1deg_at_1m_image_only(rig, reset, tilt_deg):
    scene, _, K, detector = rig
    R = pin.rpy.rpyToMatrix(np.radians(tilt_deg), np.radians(tilt_deg / 3), 0.4)
    set_free_body(scene, 0, np.array([0.1, 0.12, 0.15]), R)
    gray, _, X_WC = look(rig)
    (d,) = [d for d in detector.detect(gray, K) if d.tag_id == 5]
    X_CT = truth(scene, X_WC, "tag5")
    assert np.linalg.norm(X_CT.translation) == pytest.approx(0.86, abs=0.05)
    dp, dr = errors(X_CT, d.X_CT)
    assert dp < 5e-3 and dr < 1.0, (dp, dr)


@pytest.mark.parametrize("tilt_deg", [0.0, 15.0])
def test_tag_pose_within_5mm_and_1deg_at_1m_with_depth(rig, reset, tilt_deg):
    # Face-on, the corners alone leave the tilt to within a few degrees (rendered texture
    # edges are ~0.2 px off); the depth plane pins it.
    scene, _, K, detector = rig
    set_free_body(
        scene, 0, np.array([0.1, 0.12, 0.01]), pin.rpy.rpyToMatrix(np.radians(tilt_deg), 0.0, 0.4)
    )
    gray, depth, X_WC = look(rig)
    (d,) = [d for d in detector.detect(gray, K, depth=depth) if d.tag_id == 5]
    dp, dr = errors(truth(scene, X_WC, "tag5"), d.X_CT)
    assert dp < 5e-3 and dr < 1.0, (dp, dr)


def test_plank_pose_from_three_tags_and_from_one_when_the_others_are_occluded(rig, reset):
    scene, _, K, detector = rig
    set_free_body(scene, 1, np.array([-0.1, -0.08, 0.05]), pin.rpy.rpyToMatrix(0.3, -0.2, 0.5))
    gray, depth, X_WC = look(rig)
    X_CB = X_WC.inverse() * pin.SE3(scene.body_pose("plank"))
    pose = estimate_body_pose(PLANK, detector.detect(gray, K, depth=depth), K, depth=depth)
    assert pose.tag_ids == (30, 31, 32)
    dp, dr = errors(X_CB, pose.X_CB)
    assert dp < 5e-3 and dr < 1.0, (dp, dr)

    # A card 20 x 20 cm, 10 cm above the plank, over tags 30 and 31.
    X_WB = pin.SE3(scene.body_pose("plank"))
    card = X_WB * pin.SE3(np.eye(3), np.array([-0.07, 0.0, 0.12]))
    set_free_body(scene, 2, card.translation, card.rotation)
    gray, depth, _ = look(rig)
    detections = detector.detect(gray, K, depth=depth)
    assert [d.tag_id for d in detections if d.tag_id in (30, 31, 32)] == [32]
    pose = estimate_body_pose(PLANK, detections, K, depth=depth)
    assert pose.tag_ids == (32,)
    dp, dr = errors(X_CB, pose.X_CB)
    assert dp < 5e-3 and dr < 1.0, (dp, dr)


def test_talos_head_camera_in_the_plank_scene(rig):
    """The demo scene (models/scenes/talos_plank.xml): TALOS looks down at the table (torso
    0.2 rad, head 0.78 rad); tags 4, 5 (table) and 10, 11 (plank) are detected within
    5 mm / 1 deg with depth, the plank's and table's poses too, and the camera pose that
    ``perceive`` computes with Pinocchio from the robot's joints is MuJoCo's."""
    from marionette import robots
    from marionette._core import sim
    from marionette.perception.objects import load_tagged_bodies, tag_sizes

    scene = sim.MjScene(str(marionette.MODELS_DIR / "scenes" / "talos_plank.xml"))
    scene.reset_keyframe("reference")
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    qpos = scene.qpos.copy()
    n = robots.mujoco_nq("talos")  # the robot's block of qpos (its moving fingers included)
    q = robots.mujoco_to_pinocchio("talos", qpos[:n])
    for joint, value in (("torso_2_joint", 0.2), ("head_1_joint", 0.78)):
        q[model.joints[model.getJointId(joint)].idx_q] = value
    qpos[:n] = robots.pinocchio_to_mujoco("talos", q)
    scene.qpos = qpos
    scene.forward()
    renderer = sim.RgbdRenderer(scene, "head_rgbd", 640, 480)
    k = renderer.intrinsics
    K = CameraIntrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    rgb, depth = renderer.render(scene)
    gray = np.rint(rgb.mean(axis=2)).astype(np.uint8)
    X_WC = pin.SE3(renderer.camera_pose(scene))

    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    X_WC_pin = data.oMf[model.getFrameId(robots.robot("talos").camera_frame)]
    assert np.allclose(X_WC_pin.homogeneous, X_WC.homogeneous, atol=1e-6)

    bodies = load_tagged_bodies(
        [marionette.MODELS_DIR / "objects" / f"{n}.yaml" for n in ("plank", "table")]
    )
    detector = AprilTagDetector(DetectorConfig(tag_sizes=tag_sizes(bodies)))
    detections = detector.detect(gray, K, depth=depth)
    # 14, 15: the plank's end face on top. Tag 11, on the shaded front face just under them, is
    # no longer found, from here nor along the demo's approach (mjcf_tag_render_test.cc says
    # why); 14, 15 measure the plank on the approach (test_visual_servo.py).
    assert sorted(d.tag_id for d in detections) == [4, 5, 10, 14, 15]
    for d in detections:
        dp, dr = errors(truth(scene, X_WC, f"tag/{d.tag_id}"), d.X_CT)
        assert dp < 5e-3 and dr < 1.0, (d.tag_id, dp, dr)
    for body in bodies:
        pose = estimate_body_pose(body, detections, K, depth=depth)
        X_CB = X_WC.inverse() * pin.SE3(scene.body_pose(body.name))
        dp, dr = errors(X_CB, pose.X_CB)
        assert dp < 5e-3 and dr < 1.0, (body.name, dp, dr)
