"""The drill demo's geometry (thesis 000 §6.3) against closed forms and brute force, without
processes: part pose from two reference holes, the seeded displacement's bounds, the tool target,
the scene camera and the displaced scene file."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from marionette.execution.tool_task import axis_angle_deg, tool_target
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.objects import load_tagged_bodies
from marionette.scenarios.drill import (
    PART_YAML,
    SCENE,
    DrillSettings,
    displaced_scene,
    draw_displacement,
    part_pose_from_references,
    scene_camera,
)


def test_part_pose_from_two_holes_and_axis_is_exact_on_exact_data():
    rng = np.random.default_rng(0)
    p1_P, p2_P = np.array([0.01, -0.16, 1.02]), np.array([0.01, 0.16, 0.88])
    a_P = np.array([-1.0, 0.0, 0.0])
    for _ in range(20):
        X = pin.SE3.Random()
        X_est = part_pose_from_references(X * p1_P, X * p2_P, X.rotation @ a_P, p1_P, p2_P, a_P)
        assert np.allclose(X_est.homogeneous, X.homogeneous, atol=1e-12)
        # any other point of the part follows (the interpolation of the remaining holes)
        q = rng.normal(size=3)
        assert np.allclose(X_est * q, X * q, atol=1e-12)


def test_part_pose_refuses_references_on_one_axis():
    p1 = np.zeros(3)
    with pytest.raises(ValueError, match="one hole axis"):
        part_pose_from_references(
            p1, p1 + [0.1, 0, 0], np.array([1.0, 0, 0]), p1, p1 + [0.1, 0, 0], np.array([1.0, 0, 0])
        )


def test_displacement_within_its_bounds_at_the_pattern_centre():
    st = DrillSettings()
    c = np.array([0.01, 0.0, 0.95])
    for seed in range(200):
        D = draw_displacement(seed, st, c)
        angle = np.degrees(np.linalg.norm(pin.log3(D.rotation)))
        moved = np.linalg.norm(D * c - c)
        assert 5.0 - 1e-9 <= angle <= 10.0 + 1e-9
        assert 0.025 - 1e-9 <= moved <= 0.05 + 1e-9
    assert not np.allclose(
        draw_displacement(1, st, c).homogeneous, draw_displacement(2, st, c).homogeneous
    )
    assert np.allclose(
        draw_displacement(3, st, c).homogeneous, draw_displacement(3, st, c).homogeneous
    )


def test_tool_target_axis_standoff_and_smallest_rotation():
    for _ in range(20):
        H = pin.SE3.Random()
        R_now = pin.SE3.Random().rotation
        X = tool_target(H, R_now, 0.01)
        assert np.allclose(X.rotation[:, 0], H.rotation[:, 0], atol=1e-12)
        assert np.allclose(X.translation, H.translation - 0.01 * H.rotation[:, 0], atol=1e-12)
        # the rotation from now to target is the smallest taking the tool axis onto the hole's:
        # its angle equals the angle between the two axes, and brute force over the masked
        # rotation about the tool axis finds none smaller
        turn = np.degrees(np.linalg.norm(pin.log3(R_now.T @ X.rotation)))
        assert turn == pytest.approx(axis_angle_deg(R_now[:, 0], H.rotation[:, 0]), abs=1e-8)
        for theta in np.linspace(-np.pi, np.pi, 361):
            R_alt = X.rotation @ pin.exp3(np.array([theta, 0.0, 0.0]))
            assert np.degrees(np.linalg.norm(pin.log3(R_now.T @ R_alt))) >= turn - 1e-8


def test_scene_camera_sees_all_part_tags():
    X_WC, fovy = scene_camera()
    K = CameraIntrinsics.from_fovy(640, 480, fovy)
    X_WP = pin.SE3(pin.exp3(np.array([0, 0, np.pi])), np.array([1.05, 0.0, 0.0]))  # ur10_drill.yaml
    body = load_tagged_bodies([PART_YAML])[0]
    for t in body.tags:
        p_C = X_WC.actInv(X_WP * t.X_BT).translation
        u, v = K.project(p_C[None, :])[0]
        assert p_C[2] > 0.3 and 0 < u < 640 and 0 < v < 480, t.tag_id
        # the tag faces the camera (its z, out of the face, points back at it)
        assert (X_WC.actInv(X_WP * t.X_BT).rotation[:, 2] @ p_C) < 0


def test_displaced_scene_carries_the_pose(tmp_path: Path):
    X = pin.SE3(pin.exp3(np.array([0.05, -0.1, 3.0])), np.array([1.07, -0.02, 0.01]))
    text = displaced_scene(X, tmp_path / "scene.xml").read_text()
    m = re.search(r'<body name="part" pos="([^"]+)" quat="([^"]+)" mocap="true">', text)
    w, x, y, z = (float(v) for v in m.group(2).split())
    assert np.allclose(np.array(m.group(1).split(), dtype=float), X.translation)
    assert np.allclose(pin.Quaternion(w, x, y, z).matrix(), X.rotation, atol=1e-10)
    assert 'meshdir=".."' not in text and text.count('<body name="part"') == 1
    assert len(text.splitlines()) == len(SCENE.read_text().splitlines())


def test_run_drill_refuses_a_running_controller(tmp_path: Path):
    from marionette.scenarios import SCENARIOS, RunOptions, ScenarioError

    with pytest.raises(ScenarioError, match="no --controller-url"):
        SCENARIOS["drill"].run(
            0, tmp_path, RunOptions(controller_url="udpm://239.255.76.67:7667?ttl=0")
        )


def test_the_spindle_view_marks_the_hole_where_the_camera_sees_it(tmp_path: Path):
    """The report's spindle image: the centre found, projected with the camera's frame, is where
    the dark disc is in the image (its darkest pixels' centroid within 1 px)."""
    from marionette.perception.hole_sensor import HoleMeasurement
    from marionette.scenarios.drill import _plot_spindle_view, spindle_view_file

    K = CameraIntrinsics.from_fovy(640, 480, 45.0)
    X_FC = pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 0.1), np.array([-0.1, 0.02, -0.01]))
    centre = X_FC * np.array([0.004, -0.003, 0.11])
    u, v = K.project(X_FC.actInv(centre))[0]
    vv, uu = np.indices((480, 640))
    gray = np.where(np.hypot(uu - u, vv - v) < 12, 30, 160).astype(np.uint8)
    m = HoleMeasurement(centre, X_FC.rotation @ [0, 0, -1.0], 5e-5, 450, 1e-4)
    path = _plot_spindle_view(tmp_path, "part/R1", 0.004, gray, K, X_FC, m)
    assert path.name == spindle_view_file("part/R1") == "spindle_R1.png" and path.stat().st_size
    dark = gray < 100
    assert np.hypot(uu[dark].mean() - u, vv[dark].mean() - v) < 1.0
