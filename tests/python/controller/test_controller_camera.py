"""The controller's head camera: RGB-D frames at the set rate (in controller time), intrinsics
from the MuJoCo camera, and depth that matches the floor plane seen from the camera pose."""

from __future__ import annotations

import math

import numpy as np

from marionette import robots
from marionette.control.client import vector_to_pose


def test_camera_frames_rate_intrinsics_and_depth(run_controller):
    scene = str(robots.MODELS_DIR / "scenes" / "talos_plank.xml")
    with run_controller("--robot", "talos", "--scene", scene, "--camera-rate", "15", camera=True) as c:
        c.wait(lambda c: c.num_images >= 30, 60, "30 camera frames")
        image = c.image
        utimes = np.array(c.image_utimes[1:])  # the first may predate our subscription
    # Rate, in controller time: frames 1/15 s apart (every 67 ticks), none skipped.
    assert set(np.diff(utimes)) == {67_000}, np.diff(utimes)
    assert image.width == 640 and image.height == 480
    assert image.frame_name == "rgbd_rgb_optical_frame"
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
