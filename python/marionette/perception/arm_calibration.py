"""Encoder offsets of an arm from its wrist tags and the head camera (thesis 000 ch. 4.2).

Chapter 4 calibrates the encoder offsets that put the hand centimetres from where the model says
(7° at the shoulder, 4° at the wrist): markers on the hand are measured in many configurations
and all of them are projected at once. Here the marker is the ring of tags around the wrist
(declared in the robot's robot.yaml, ``tags`` and ``calibration``) and the head camera measures its
full pose, so every joint of
the arm is observable (:func:`calibration.calibrate_joint_offsets_from_poses`).

1. **Views** (:func:`plan_views`): arm configurations sampled in a box in front of the robot,
   kept when the nominal model shows the ring 0.3–0.75 m from the camera, well inside the image,
   with two of its tags facing the lens, and the arm clear of the body (the robot's collision
   model); of those, ``count`` are chosen greedily for the best-conditioned problem
   (D-optimal: the largest log det J^T J of the stacked pose Jacobians).
2. **Measurements** (:func:`measure_views`): the robot holds each view (the encoders read the
   view's joint values) and the head camera takes an image: rendered by MuJoCo in the scene the
   robot lives in, tags detected by ViSP, the ring's pose estimated from all its visible tags at
   once. The camera's pose in the torso comes from the head's joints, which carry no offset.
3. **Solve** (:func:`calibrate_arm`): the offsets of the arm's seven joints, their 1-sigma, and
   the per-view residuals.

The result is what the controller's ``--encoder-offsets`` takes (an encoder reads its joint's
true angle minus the calibrated correction).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.perception.calibration import (
    CalibrationError,
    JointOffsetProblem,
    PoseOffsetResult,
    calibrate_joint_offsets_from_poses,
    pose_residuals_and_jacobian,
)
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.objects import TaggedBody, tagged_bodies_from_semantics

ROTATION_WEIGHT = 0.1  # [m/rad]: 1° of tag orientation counts as 1.7 mm


def calibrated_arm(robot: str, side: str) -> robots.CalibratedArm:
    """The arm ``side`` of ``robot``'s robot.yaml ``calibration`` section: its joints, the
    tagged link, where its views are sampled, the head postures that look at it."""
    desc = robots.robot(robot)
    for arm in desc.calibrated_arms:
        if arm.side == side:
            return arm
    sides = [a.side for a in desc.calibrated_arms]
    raise CalibrationError(
        f"{desc.semantics}: calibration declares no arm {side!r}"
        + (f" (arms: {', '.join(sides)})" if sides else " (no calibration section)")
    )


def calibration_frames(robot: str) -> tuple[str, str]:
    """(base frame of the arm poses, camera optical frame) of ``robot``'s robot.yaml; raises
    :class:`CalibrationError` naming the file when either is missing."""
    desc = robots.robot(robot)
    if desc.calibration_base_frame is None:
        raise CalibrationError(f"{desc.semantics}: calibration declares no base_frame")
    if desc.camera_frame is None:
        raise CalibrationError(f"{desc.semantics}: no camera to calibrate with (cameras)")
    return desc.calibration_base_frame, desc.camera_frame


def arm_joints(robot: str, side: str) -> tuple[str, ...]:
    return calibrated_arm(robot, side).joints


def wrist_ring(robot: str, side: str) -> TaggedBody:
    """The tags on ``side``'s wrist as the robot's model declares them (robot.yaml)."""
    link = calibrated_arm(robot, side).tagged_link
    for body in tagged_bodies_from_semantics(robots.semantics(robot)):
        if body.link == link:
            return body
    raise CalibrationError(f"{robot} declares no tags on {link}")


def ring_visibility(
    model: pin.Model,
    data: pin.Data,
    q: np.ndarray,
    ring: TaggedBody,
    intrinsics: CameraIntrinsics,
    camera_frame: str,
    margin_px: float = 60.0,
) -> int:
    """How many of the ring's tags face the camera (within 55° of its line of sight) with their
    centre inside the image by ``margin_px``, 0.3–0.75 m away (nominal kinematics at ``q``)."""
    pin.framesForwardKinematics(model, data, q)
    X_CE = data.oMf[model.getFrameId(camera_frame)].actInv(data.oMf[model.getFrameId(ring.link)])
    facing = 0
    for tag in ring.tags:
        X_CT = X_CE * tag.X_BT
        p = X_CT.translation
        if not 0.3 < p[2] < 0.75:
            continue
        u, v = intrinsics.project(p)[0]
        if not (
            margin_px < u < intrinsics.width - margin_px
            and margin_px < v < intrinsics.height - margin_px
        ):
            continue
        if -X_CT.rotation[:, 2] @ (p / np.linalg.norm(p)) > np.cos(np.radians(55.0)):
            facing += 1
    return facing


def plan_views(
    model: pin.Model,
    geom: pin.GeometryModel,
    q_stand: np.ndarray,
    robot: str,
    side: str,
    ring: TaggedBody,
    intrinsics: CameraIntrinsics,
    camera_frame: str,
    count: int = 10,
    candidates: int = 6000,
    seed: int = 0,
) -> list[np.ndarray]:
    """``count`` configurations (nq,) of the standing robot ``q_stand`` with ``side``'s arm and
    the head moved so that the camera sees the wrist ``ring`` (module doc, step 1): arm joints
    drawn in the arm's ``sampling_box``, the head in one of its ``head_postures`` (robot.yaml).
    Raises :class:`CalibrationError` when fewer than ``count`` candidates qualify."""
    rng = np.random.default_rng(seed)
    data, gdata = model.createData(), pin.GeometryData(geom)
    desc, arm = robots.robot(robot), calibrated_arm(robot, side)
    iq = [model.joints[model.getJointId(j)].idx_q for j in arm.joints]
    ih = [model.joints[model.getJointId(j)].idx_q for j in desc.calibration_head_joints]
    lo, hi = np.array(arm.sampling_box).T
    keep: list[np.ndarray] = []
    for _ in range(candidates):
        q = q_stand.copy()
        q[iq] = lo + rng.random(len(iq)) * (hi - lo)
        q[ih] = arm.head_postures[rng.integers(len(arm.head_postures))]
        if ring_visibility(model, data, q, ring, intrinsics, camera_frame) < 2:
            continue
        if pin.computeCollisions(model, data, geom, gdata, q, True):
            continue
        keep.append(q)
    if len(keep) < count:
        raise CalibrationError(
            f"only {len(keep)} of {candidates} sampled {side}-arm configurations show the "
            f"wrist ring to the camera clear of the body; {count} needed"
        )
    # Greedy D-optimal choice: each view adds J_i^T J_i of its pose residual w.r.t. the offsets.
    base, _ = calibration_frames(robot)
    problem = JointOffsetProblem(model, base, arm.tagged_link, arm.joints)
    infos = []
    for q in keep:
        pin.framesForwardKinematics(model, data, q)
        X = data.oMf[model.getFrameId(base)].inverse() * data.oMf[model.getFrameId(arm.tagged_link)]
        _, J = pose_residuals_and_jacobian(
            problem, q[None], [X], np.zeros(len(iq)), ROTATION_WEIGHT
        )
        infos.append(J.T @ J)
    chosen: list[int] = []
    total = 1e-9 * np.eye(len(iq))
    for _ in range(count):
        scores = [
            np.linalg.slogdet(total + info)[1] if i not in chosen else -np.inf
            for i, info in enumerate(infos)
        ]
        best = int(np.argmax(scores))
        chosen.append(best)
        total = total + infos[best]
    return [keep[i] for i in chosen]


@dataclass(frozen=True)
class WristView:
    q: np.ndarray  # (nq,) encoder readings (and the base's pose)
    X_BE: pin.SE3 | None  # measured tagged link in the base frame; None: ring not seen
    tag_ids: tuple[int, ...]
    reprojection_px: float


def measure_views(
    scene,
    renderer,
    model: pin.Model,
    robot: str,
    ring: TaggedBody,
    views: list[np.ndarray],
    quad_decimate: float = 1.0,
    max_reprojection_px: float = 1.0,
    image_noise: float = 2.0,
    seed: int = 0,
) -> list[WristView]:
    """The robot holds each view in the MuJoCo ``scene`` (an ``MjScene``: its encoders, offsets
    included, read the view's joint values) and the head camera's image (``renderer``), with
    Gaussian sensor noise of ``image_noise`` grey levels, locates the ``ring`` (module doc, step
    2). A view whose ring is unseen, seen through one tag only, or fitted worse than
    ``max_reprojection_px`` gets ``X_BE`` None."""
    from marionette.perception.detector import AprilTagDetector, DetectorConfig
    from marionette.perception.objects import estimate_body_pose, tag_sizes

    data = model.createData()
    base_frame, camera_frame = calibration_frames(robot)
    K = _intrinsics(renderer)
    detector = AprilTagDetector(
        DetectorConfig(tag_sizes=tag_sizes([ring]), quad_decimate=quad_decimate)
    )
    rng = np.random.default_rng(seed)
    out = []
    for q in views:
        robot_qpos = robots.pinocchio_to_mujoco(robot, q)
        qpos = scene.qpos.copy()
        qpos[: len(robot_qpos)] = robot_qpos
        scene.qpos = qpos
        scene.forward()
        rgb, depth = renderer.render(scene)
        gray = np.clip(
            np.rint(rgb.mean(axis=2) + rng.normal(0.0, image_noise, depth.shape)), 0, 255
        )
        gray = gray.astype(np.uint8)
        pose = estimate_body_pose(ring, detector.detect(gray, K, depth=depth), K, depth=depth)
        if pose is None or len(pose.tag_ids) < 2 or pose.reprojection_rms > max_reprojection_px:
            out.append(
                WristView(
                    q, None, pose.tag_ids if pose else (), pose.reprojection_rms if pose else np.nan
                )
            )
            continue
        pin.framesForwardKinematics(model, data, q)
        X_BC = data.oMf[model.getFrameId(base_frame)].actInv(
            data.oMf[model.getFrameId(camera_frame)]
        )
        out.append(WristView(q, X_BC * pose.X_CB, pose.tag_ids, pose.reprojection_rms))
    return out


def _intrinsics(renderer) -> CameraIntrinsics:
    k = renderer.intrinsics
    return CameraIntrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)


@dataclass(frozen=True)
class ArmCalibration:
    side: str
    joints: tuple[str, ...]
    result: PoseOffsetResult
    views_planned: int
    views_used: int

    def encoder_offsets(self) -> dict[str, float]:
        """joint -> how far its encoder reads above the true angle (the controller's
        ``--encoder-offsets``): minus the correction."""
        return {j: -float(c) for j, c in zip(self.joints, self.result.offsets)}

    def summary(self) -> dict:
        r = self.result
        return {
            "side": self.side,
            "views_planned": self.views_planned,
            "views_used": self.views_used,
            "encoder_offsets_deg": {
                j: float(np.degrees(v)) for j, v in self.encoder_offsets().items()
            },
            "offsets_std_deg": {
                j: float(np.degrees(s)) for j, s in zip(self.joints, r.offsets_std)
            },
            "residual_position_mm": float(np.median(r.position_residuals) * 1e3),
            "residual_rotation_deg": float(np.degrees(np.median(r.rotation_residuals))),
        }


def encoder_offsets_argument(offsets: dict[str, float]) -> str:
    """The value of the controller's ``--encoder-offsets``: ``joint=offset,...`` [rad]."""
    return ",".join(f"{joint}={offset:.9f}" for joint, offset in offsets.items())


def calibrate_arm(
    scene_path: Path,
    side: str,
    robot: str,
    count: int = 12,
    seed: int = 0,
    log: Callable[[str], None] = print,
) -> ArmCalibration:
    """Plans ``count`` views, measures them in ``scene_path`` and solves the seven offsets of
    ``side``'s arm. Raises :class:`CalibrationError` when fewer than 4 views see the ring."""
    from marionette._core import sim

    model, geom = robots.load_pinocchio(robot, with_collision=True)
    desc = robots.robot(robot)
    ring = wrist_ring(robot, side)
    base_frame, camera_frame = calibration_frames(robot)
    scene = sim.MjScene(str(scene_path))
    scene.reset_keyframe("reference")
    renderer = sim.RgbdRenderer(scene, desc.camera, 640, 480)
    q_stand = robots.mujoco_to_pinocchio(
        robot, scene.qpos[: len(robots.pinocchio_to_mujoco(robot, pin.neutral(model)))]
    )
    views = plan_views(
        model,
        geom,
        q_stand,
        robot,
        side,
        ring,
        _intrinsics(renderer),
        camera_frame,
        count=count,
        seed=seed,
    )
    measured = [
        v
        for v in measure_views(scene, renderer, model, robot, ring, views, seed=seed)
        if v.X_BE is not None
    ]
    log(f"calibration: {side} arm, {len(measured)}/{len(views)} views saw the wrist ring")
    if len(measured) < 4:
        raise CalibrationError(
            f"only {len(measured)} of {len(views)} views saw the {side} wrist ring (4 needed)"
        )
    arm = calibrated_arm(robot, side)
    problem = JointOffsetProblem(model, base_frame, arm.tagged_link, arm.joints)
    result = calibrate_joint_offsets_from_poses(
        problem, np.array([v.q for v in measured]), [v.X_BE for v in measured], ROTATION_WEIGHT
    )
    return ArmCalibration(side, arm.joints, result, len(views), len(measured))
