"""The controller's head camera: RGB-D frames at the set rate (in controller time), intrinsics
from the MuJoCo camera, and depth that matches the floor plane seen from the camera pose."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest

from marionette import robots
from marionette.control.client import vector_to_pose


@pytest.mark.slow
def test_camera_frames_rate_intrinsics_and_depth(run_controller):
    scene = str(robots.MODELS_DIR / "scenes" / "talos_plank.xml")
    with run_controller(
        "--robot", "talos", "--scene", scene, "--camera-rate", "15", camera=True
    ) as c:
        c.wait(lambda c: c.num_images >= 30, 60, "30 camera frames")
        image = c.image
        utimes = np.array(c.image_utimes[1:])  # the first may predate our subscription
    # Rate, in controller time: frames 1/15 s apart (every 67 ticks), none skipped.
    assert set(np.diff(utimes)) == {67_000}, np.diff(utimes)
    assert image.width == 640 and image.height == 480
    # The frame the images are stamped with is the one the robot's description names.
    assert image.frame_name == robots.robot("talos").camera_frame
    # Intrinsics of a 45° vertical field of view (models/README.md): fy = (h/2) / tan(fovy/2).
    assert math.isclose(image.fy, 240.0 / math.tan(math.radians(22.5)), rel_tol=1e-9)
    assert image.fx == image.fy and image.cx == 319.5 and image.cy == 239.5
    rgb = np.frombuffer(bytes(image.rgb), dtype=np.uint8).reshape(480, 640, 3)
    assert rgb.std() > 5.0, "a rendered image, not a blank one"
    # Depth of the floor (z = 0) seen from the camera pose the message carries.
    depth = np.array(image.depth, dtype=float).reshape(480, 640) * image.depth_scale
    X_WC = vector_to_pose([*image.camera_position, *image.camera_quaternion])
    errors = []
    for v in range(400, 480, 8):
        for u in range(0, 640, 40):
            ray_c = np.array([(u - image.cx) / image.fx, (v - image.cy) / image.fy, 1.0])
            ray_w = X_WC.rotation @ ray_c
            expected = -X_WC.translation[2] / ray_w[2]  # along the optical axis (ray_c z = 1)
            errors.append(depth[v, u] - expected)
    errors = np.abs(errors)
    assert errors.max() < 0.01, f"depth off by up to {errors.max():.4f} m"


def _two_frames(run_controller, *args: str) -> tuple[np.ndarray, np.ndarray]:
    """Two consecutive head-camera frames (RGB, float) of TIAGo standing in the deburr scene."""
    scene = str(robots.MODELS_DIR / "scenes" / "tiago_deburr.xml")
    with run_controller(
        "--robot", "tiago", "--scene", scene, "--camera-rate", "15", *args, camera=True
    ) as c:
        c.wait(lambda c: c.num_images >= 30, 60, "30 camera frames (the robot settled)")
        first, n = c.image, c.num_images
        c.wait(lambda c: c.num_images >= n + 1, 30, "one more camera frame")
        second = c.image
    return tuple(
        np.frombuffer(bytes(i.rgb), dtype=np.uint8).reshape(480, 640, 3).astype(float)
        for i in (first, second)
    )


@pytest.mark.slow
def test_camera_noise_has_the_requested_sigma(run_controller):
    """--camera-noise 3: TIAGo holds still (without noise two frames differ in < 0.1 % of their
    values, by one grey level at most: checked first), so two noisy frames differ by the noise
    alone, whose per-frame sigma is std(a - b) / sqrt(2)."""
    a, b = _two_frames(run_controller)
    # The robot's residual sway changes ~40 of the 921600 values by one grey level in some runs.
    changed, worst = (a != b).mean(), np.abs(a - b).max()
    assert changed < 1e-3 and worst <= 1.0, (
        f"the still scene changes: {changed:.2%} of the values, by up to {worst:g}"
    )
    a, b = _two_frames(run_controller, "--camera-noise", "3")
    inside = ((a > 15) & (a < 240) & (b > 15) & (b < 240)).all(axis=2)  # no channel clamped
    assert inside.mean() > 0.5
    d = (a - b)[inside]  # (n x 3)
    # Luminance noise: one draw per pixel on R, G and B alike.
    assert (d[:, 0] == d[:, 1]).mean() > 0.999 and (d[:, 0] == d[:, 2]).mean() > 0.999
    sigma = d[:, 0].std() / math.sqrt(2.0)
    # sqrt(9 + 1/12) = 3.01: the rounding to integers adds 1/12 to the variance.
    assert 2.9 < sigma < 3.13, f"measured noise sigma {sigma:.3f} grey levels for 3"


def test_negative_camera_noise_is_refused(build_dir):
    binary = build_dir / "marionette-controller"
    for flag in ("--camera-noise", "--depth-noise"):
        out = subprocess.run(
            [binary, "--robot", "talos", "--duration", "0.01", "--lcm-url", "memq://", flag, "-1"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode != 0 and flag in out.stderr, (flag, out.returncode, out.stderr)
