"""Encoder offsets of an arm from its wrist tags and the head camera (thesis 000 ch. 4.2).

Chapter 4 calibrates the encoder offsets that put the hand centimetres from where the model says
(7° at the shoulder, 4° at the wrist): markers on the hand are measured in many configurations
and all of them are projected at once. Here the marker is the ring of tags around the wrist
(declared in the robot's robot.yaml, ``tags`` and ``calibration``) and the head camera measures its
full pose, so every joint of
the arm is observable (:func:`calibration.calibrate_joint_offsets_from_poses`).

1. **Views** (:func:`plan_views`): arm configurations sampled in a box in front of the robot,
   kept when the model shows the ring 0.3–0.75 m from the camera, well inside the image, with
   two of its tags facing the lens unhidden by the robot's other links (:class:`LineOfSight`),
   and the arm clear of the body (the robot's collision model);
   of those, ``count`` are chosen greedily for the best-conditioned problem (D-optimal: the
   largest log det J^T J of the stacked pose Jacobians). The offsets are what is unknown: a view
   planned on the nominal model may show the camera nothing once the shoulder is 7° off (the
   wrist moves by centimetres and turns its tags away). So views are planned against offset
   hypotheses (:func:`offset_hypotheses`: the current estimate and the corners of the range
   still uncertain around it, the arm's ``max_offset_deg`` in robot.yaml at first) and the views
   the ring stays visible from under most of them are preferred.
2. **Measurements** (:func:`measure_views`): the robot holds each view (the encoders read the
   view's joint values) and the head camera takes an image: rendered by MuJoCo in the scene the
   robot lives in, tags detected by ViSP, the ring's pose estimated from all its visible tags at
   once. The camera's pose in the torso comes from the head's joints, which carry no offset.
3. **Solve and re-plan** (:func:`calibrate_arm`): the offsets of the arm's seven joints, their
   1-sigma, and the per-view residuals. When fewer views than planned saw the ring, the views
   that did give a first estimate (a prior of the declared range keeps it determined from even
   one view, :func:`prior_estimate`) and the next views are planned on it (rounds, at most
   ``max_rounds``): whatever the sign and size of the offsets within the declared range, the
   ring is found. Still fewer than 4 views: :class:`CalibrationError` with the reason.

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
from marionette.perception.visibility import LineOfSight, ViewLimits, tags_in_view

ROTATION_WEIGHT = 0.1  # [m/rad]: 1° of tag orientation counts as 1.7 mm
# A view is planned with two tags within this of the line of sight: at 55° one of them was missed
# in most rendered views (32 mm tags ~0.5 m away, 640 x 480).
FACING_DEG = 45.0


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
    sight: LineOfSight | None = None,
    max_angle_deg: float = 55.0,
) -> int:
    """How many of the ring's tags face the camera (within ``max_angle_deg`` of its line of
    sight) with their centre inside the image by ``margin_px``, 0.3–0.75 m away (nominal
    kinematics at ``q``), and, with ``sight``, not hidden by the robot's other links."""
    pin.framesForwardKinematics(model, data, q)
    if sight is not None:
        sight.update(data)
    return tags_in_view(
        data.oMf[model.getFrameId(camera_frame)],
        data.oMf[model.getFrameId(ring.link)],
        ring,
        intrinsics,
        ViewLimits(margin_px=margin_px, max_angle_deg=max_angle_deg),
        sight,
    )


def offset_hypotheses(
    center: np.ndarray, spread: float | np.ndarray, count: int, rng: np.random.Generator
) -> np.ndarray:
    """(count, k) encoder-offset hypotheses [rad]: ``center`` (k,) first, then corners of the
    box ``center`` ± ``spread`` with random signs (the wrist moves most at a corner)."""
    center = np.asarray(center, dtype=float)
    signs = rng.choice([-1.0, 1.0], size=(max(count - 1, 0), len(center)))
    return np.vstack([center, center + signs * spread])


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
    offsets: np.ndarray | None = None,
) -> list[np.ndarray]:
    """``count`` configurations (nq,) of the standing robot ``q_stand`` with ``side``'s arm and
    the head moved so that the camera sees the wrist ``ring`` (module doc, step 1): arm joints
    drawn in the arm's ``sampling_box``, the head in one of its ``head_postures`` (robot.yaml).
    ``offsets`` (m, k): encoder-offset hypotheses (true angle = reading − offset), the first the
    current estimate (default: none); a candidate must show the ring under the first, and the
    ones that show it under the most hypotheses are chosen from. Raises
    :class:`CalibrationError` when fewer than ``count`` candidates qualify."""
    rng = np.random.default_rng(seed)
    data, gdata = model.createData(), pin.GeometryData(geom)
    desc, arm = robots.robot(robot), calibrated_arm(robot, side)
    iq = [model.joints[model.getJointId(j)].idx_q for j in arm.joints]
    ih = [model.joints[model.getJointId(j)].idx_q for j in desc.calibration_head_joints]
    lo, hi = np.array(arm.sampling_box).T
    H = np.zeros((1, len(iq))) if offsets is None else np.atleast_2d(offsets)
    sight = LineOfSight(model, geom, arm.tagged_link, camera_frame)

    def shown(q: np.ndarray, h: np.ndarray) -> bool:
        qt = q.copy()
        qt[iq] -= h
        seen = ring_visibility(
            model, data, qt, ring, intrinsics, camera_frame, sight=sight, max_angle_deg=FACING_DEG
        )
        return seen >= 2

    keep: list[np.ndarray] = []
    robust: list[int] = []
    for _ in range(candidates):
        q = q_stand.copy()
        q[iq] = lo + rng.random(len(iq)) * (hi - lo)
        q[ih] = arm.head_postures[rng.integers(len(arm.head_postures))]
        if not shown(q, H[0]):
            continue
        qt = q.copy()
        qt[iq] -= H[0]
        if pin.computeCollisions(model, data, geom, gdata, qt, True):
            continue
        keep.append(q)
        robust.append(1 + sum(shown(q, h) for h in H[1:]))
    if len(keep) < count:
        raise CalibrationError(
            f"only {len(keep)} of {candidates} sampled {side}-arm configurations show the "
            f"wrist ring to the camera clear of the body; {count} needed"
        )
    # The most robust candidates (at least ``count``), then the greedy D-optimal choice among
    # them: each view adds J_i^T J_i of its pose residual w.r.t. the offsets.
    bar = sorted(robust, reverse=True)[count - 1]
    keep = [q for q, r in zip(keep, robust) if r >= bar]
    base, _ = calibration_frames(robot)
    problem = JointOffsetProblem(model, base, arm.tagged_link, arm.joints)
    infos = []
    for q in keep:
        qt = q.copy()
        qt[iq] -= H[0]
        pin.framesForwardKinematics(model, data, qt)
        X = data.oMf[model.getFrameId(base)].inverse() * data.oMf[model.getFrameId(arm.tagged_link)]
        _, J = pose_residuals_and_jacobian(
            problem, qt[None], [X], np.zeros(len(iq)), ROTATION_WEIGHT
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


def prior_estimate(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: list[pin.SE3],
    prior_sigma: float,
    noise_m: float = 0.005,
) -> np.ndarray:
    """Offset corrections (k,) [rad] (true = reading + correction) from however few views Q
    (N, nq) with their measured poses, under a zero-mean prior of ``prior_sigma`` [rad] per
    joint: a view's weighted residual of ``noise_m`` costs as much as a correction of
    ``prior_sigma`` (one view, 6 equations, still fixes 7 offsets). A first estimate to plan the
    next views on, not the calibration."""
    from scipy.optimize import least_squares

    k = len(problem.joints)
    w = noise_m / prior_sigma

    def residuals(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, J = pose_residuals_and_jacobian(problem, Q, measured, x, ROTATION_WEIGHT)
        return np.concatenate([r, w * x]), np.vstack([J, w * np.eye(k)])

    return least_squares(lambda x: residuals(x)[0], np.zeros(k), jac=lambda x: residuals(x)[1]).x


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
    rounds: int = 1  # view plannings (the later ones on the estimate of the earlier views)

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
            "rounds": self.rounds,
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


MIN_VIEWS = 4  # views that saw the ring, for the seven offsets and outlier rejection
HYPOTHESES = 8  # offset hypotheses a view is planned against


def calibrate_arm(
    scene_path: Path,
    side: str,
    robot: str,
    count: int = 12,
    seed: int = 0,
    log: Callable[[str], None] = print,
    max_rounds: int = 3,
) -> ArmCalibration:
    """Plans ``count`` views, measures them in ``scene_path`` and solves the seven offsets of
    ``side``'s arm; re-plans on the estimate while a round's views mostly missed the ring
    (module doc, step 3), ``max_rounds`` plannings at most. Raises :class:`CalibrationError`
    when fewer than 4 views saw the ring in all."""
    from marionette._core import sim

    model, geom = robots.load_pinocchio(robot, with_collision=True)
    desc = robots.robot(robot)
    arm = calibrated_arm(robot, side)
    ring = wrist_ring(robot, side)
    base_frame, camera_frame = calibration_frames(robot)
    scene = sim.MjScene(str(scene_path))
    scene.reset_keyframe("reference")
    renderer = sim.RgbdRenderer(scene, desc.camera, 640, 480)
    q_stand = robots.mujoco_to_pinocchio(
        robot, scene.qpos[: len(robots.pinocchio_to_mujoco(robot, pin.neutral(model)))]
    )
    problem = JointOffsetProblem(model, base_frame, arm.tagged_link, arm.joints)
    rng = np.random.default_rng(seed)
    max_offset = np.radians(arm.max_offset_deg)
    estimate, spread = np.zeros(len(arm.joints)), max_offset  # encoder offsets [rad]
    seen: list[WristView] = []
    planned = 0
    result: PoseOffsetResult | None = None
    for round_ in range(1, max_rounds + 1):
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
            seed=seed + 1000 * (round_ - 1),
            offsets=offset_hypotheses(estimate, spread, HYPOTHESES, rng),
        )
        planned += len(views)
        new = [
            v
            for v in measure_views(
                scene, renderer, model, robot, ring, views, seed=seed + round_ - 1
            )
            if v.X_BE is not None
        ]
        seen += new
        log(
            f"calibration: {side} arm, round {round_}: {len(new)}/{len(views)} views saw the "
            f"wrist ring (planned for offsets within {np.degrees(np.max(spread)):.1f}° of "
            f"[{', '.join(f'{np.degrees(e):+.1f}' for e in estimate)}]°)"
        )
        Q = np.array([v.q for v in seen]) if seen else np.zeros((0, model.nq))
        if len(seen) >= MIN_VIEWS:
            result = calibrate_joint_offsets_from_poses(
                problem, Q, [v.X_BE for v in seen], ROTATION_WEIGHT
            )
            if len(seen) >= max(MIN_VIEWS, count // 2) and len(new) >= len(views) // 2:
                break
            estimate = -result.offsets
            spread = np.clip(3.0 * result.offsets_std, np.radians(0.5), max_offset)
        elif seen:
            estimate = -prior_estimate(problem, Q, [v.X_BE for v in seen], max_offset)
            spread = max_offset / 2.0
        else:
            spread = max_offset  # nothing seen: other views, other hypotheses
    if result is None:
        raise CalibrationError(
            f"only {len(seen)} of {planned} views saw the {side} wrist ring in {max_rounds} "
            f"rounds of view planning ({MIN_VIEWS} needed): offsets beyond the declared "
            f"±{arm.max_offset_deg:g}°, or the ring hidden"
        )
    return ArmCalibration(side, arm.joints, result, planned, len(seen), round_)
