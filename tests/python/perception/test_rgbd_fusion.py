"""The RGB-D fusion (``marionette._visp.refine_pose_rgbd`` through ``estimate_body_pose``) is
honest about depth noise: on synthetic frames of a small tilted tag (exact ground truth,
:mod:`marionette.perception.synthetic`), drawn at random distances, tilts and tilt axes, the fused
rotation is no worse than the image alone at any depth noise (RMS over the draws, the
measure a maximum-likelihood fusion minimises; both weights honest), whatever depth noise the caller
assumes, and the noise it weighted with is the one in the frames.

Reference: the pose the frame was rendered at. The image-alone estimate is the baseline the
fusion must not degrade (the corners of a 4 cm tag at 0.8 m already give its tilt to ~0.4 deg)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette import _visp
from marionette.perception import synthetic as syn
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import AprilTagDetector, DetectorConfig, rotation_angle
from marionette.perception.objects import TaggedBody, TagOnBody, estimate_body_pose

K = CameraIntrinsics.from_fovy(640, 480, 45.0)
SIZE = 0.04  # [m] a tool tag of the deburring demo
TAG = 3
BODY = TaggedBody("tool", "tool", (TagOnBody(TAG, SIZE, pin.SE3.Identity()),))
DRAWS = 24


def _frames(depth_noise: float):
    """(X_CT, frame, detection) per draw: the tag 0.6-1.0 m away, tilted 20-45 deg about a random
    in-plane axis, 2 grey levels of image noise and ``depth_noise`` [m] on the depth."""
    detector = AprilTagDetector(
        DetectorConfig(tag_sizes={TAG: SIZE}, quad_decimate=1.0, refine_with_depth=False)
    )
    out = []
    for k in range(DRAWS):
        rng = np.random.default_rng(100 + k)
        axis = np.array([*rng.normal(size=2), 0.0])
        p = [rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), rng.uniform(0.6, 1.0)]
        X_CT = syn.look_at(p, rng.uniform(20.0, 45.0), axis)
        frame = syn.render(
            K,
            [syn.tag_quad(TAG, SIZE, X_CT)],
            background_depth=1.8,
            noise_std=2.0,
            depth_noise_std=depth_noise,
            rng=rng,
        )
        (found,) = [d for d in detector.detect(frame.gray, K) if d.tag_id == TAG]
        out.append((X_CT, frame, found))
    return out


def corner_noise_px(frames) -> float:
    """RMS distance [px] of the detected corners from their true projections."""
    errors = []
    for X_CT, _, found in frames:
        truth = np.array([K.project(X_CT.act(p)).ravel() for p in BODY.corners_B(TAG)])
        errors += [np.min(np.linalg.norm(truth - c, axis=1)) for c in found.corners]
    return float(np.sqrt(np.mean(np.square(errors))))


def _rotation_errors_deg(frames, assumed_depth_noise: float | None) -> np.ndarray:
    """Per frame, the estimate's rotation error; None: the image alone. The corners are weighted
    with the noise they have (the fusion is optimal when both weights are honest)."""
    corners = corner_noise_px(frames)
    errors = []
    for X_CT, frame, found in frames:
        if assumed_depth_noise is None:
            est = estimate_body_pose(BODY, [found], K, corner_noise_px=corners)
        else:
            est = estimate_body_pose(
                BODY,
                [found],
                K,
                depth=frame.depth,
                depth_sigma=assumed_depth_noise,
                corner_noise_px=corners,
            )
        errors.append(np.degrees(rotation_angle(est.X_CB.rotation, X_CT.rotation)))
    return np.array(errors)


@pytest.mark.parametrize("depth_noise", [0.0, 0.001, 0.003, 0.006])
def test_the_fused_rotation_is_no_worse_than_the_image_alone(depth_noise):
    frames = _frames(depth_noise)
    image = _rotation_errors_deg(frames, None)
    for assumed in (0.001, 0.003, 0.01):  # what the caller believes changes nothing
        fused = _rotation_errors_deg(frames, assumed)
        rms_fused, rms_image = np.sqrt(np.mean(fused**2)), np.sqrt(np.mean(image**2))
        print(
            f"depth noise {depth_noise * 1e3:.0f} mm, assumed {assumed * 1e3:.0f} mm: fused "
            f"RMS {rms_fused:.2f} / max {fused.max():.2f} deg, image alone "
            f"{rms_image:.2f} / {image.max():.2f} deg"
        )
        assert rms_fused <= rms_image
        assert np.max(fused) <= np.max(image)


@pytest.mark.parametrize("depth_noise", [0.001, 0.003, 0.006])
def test_the_depth_noise_weighted_with_is_the_frames(depth_noise):
    sigmas = []
    for _, frame, found in _frames(depth_noise):
        planes = [(found.corners, np.array([0.0, 0.0, 1.0]), 0.0)]
        p_B = BODY.corners_B(TAG)
        fused = _visp.refine_pose_rgbd(
            p_B, found.corners, planes, frame.depth, K.native, found.X_CT.homogeneous, 0.3, 0.01
        )
        assert fused.ok
        sigmas.append(fused.depth_sigma)
    # The robust estimate of hundreds of Gaussian samples: within a few percent of the truth.
    assert np.median(sigmas) == pytest.approx(depth_noise, rel=0.1)
    assert min(sigmas) > 0.8 * depth_noise and max(sigmas) < 1.2 * depth_noise
