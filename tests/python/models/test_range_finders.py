"""A robot's range finders (robot.yaml ``range_finders``) in its MJCF and its scenes, and the
camera carried with a tool: where it looks, what it draws."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from marionette import MODELS_DIR, robots
from marionette.models.scenes import load_scene, scene_files

WITH_RANGE_FINDERS = [n for n in robots.robot_names() if robots.robot(n).range_finders]
STANDOFF = 0.01  # [m] tool tip to the work (a hole to drill) where the camera must see it


def _range_sensors(mjcf: ET.Element) -> dict[str, str]:
    """rangefinder sensor name -> its site."""
    return {s.get("name"): s.get("site") for s in mjcf.iter("rangefinder")}


def test_a_bundled_robot_has_range_finders():
    assert WITH_RANGE_FINDERS


@pytest.mark.parametrize("name", WITH_RANGE_FINDERS)
def test_range_finders_are_rangefinders_on_sites_at_their_frames(name):
    from marionette._core import sim

    desc = robots.robot(name)
    root = ET.parse(desc.mjcf).getroot()
    sensors = _range_sensors(root)
    model, _ = robots.load_pinocchio(name, with_collision=False)
    data = model.createData()
    pin.framesForwardKinematics(model, data, robots.reference_configuration(name, model))
    scene = sim.MjScene(str(desc.mjcf))
    scene.reset_keyframe("reference")
    for r in desc.range_finders:
        assert sensors.get(r.name) == r.name, f"{desc.mjcf}: no rangefinder {r.name} on its site"
        body = next(b for b in root.iter("body") if b.find(f"site[@name='{r.name}']") is not None)
        assert body.get("name") == r.frame
        X_pin = data.oMf[model.getFrameId(r.frame)].homogeneous
        np.testing.assert_allclose(scene.site_pose(r.name), X_pin, atol=1e-9, err_msg=r.name)
    for path in scene_files(MODELS_DIR):
        if load_scene(path).robot == name:
            in_scene = _range_sensors(ET.parse(path.with_suffix(".xml")).getroot())
            assert in_scene == {r.name: r.name for r in desc.range_finders}, path


def _tool_cameras():
    """(robot, camera frame, tool gripper) for every camera on the rigid body of a tool (a
    gripper without a finger joint)."""
    out = []
    for name in robots.robot_names():
        desc = robots.robot(name)
        if not desc.cameras:
            continue
        model, _ = robots.load_pinocchio(name, with_collision=False)
        for g in robots.semantics(name).grippers:
            if g.joint:
                continue
            joint = model.frames[model.getFrameId(g.link)].parentJoint
            for c in desc.cameras:
                if model.frames[model.getFrameId(c.frame)].parentJoint == joint:
                    out.append((name, c.frame, g))
    return out


def test_a_camera_carried_with_a_tool_looks_at_the_work_beyond_its_tip():
    found = _tool_cameras()
    assert found, "a bundled robot carries a camera with its tool"
    for name, frame, g in found:
        model, _ = robots.load_pinocchio(name, with_collision=False)
        data = model.createData()
        pin.framesForwardKinematics(model, data, robots.reference_configuration(name, model))
        X_WL = data.oMf[model.getFrameId(g.link)]
        X_WG = X_WL * pin.SE3(g.pose.matrix())
        work = X_WG.act(np.array([STANDOFF, 0.0, 0.0]))  # the gripper's x is the approach
        X_WC = data.oMf[model.getFrameId(frame)]
        v = work - X_WC.translation
        z = X_WC.rotation[:, 2]
        assert v @ z > 0, f"{name}: {frame} looks away from the work of {g.name}"
        miss = np.linalg.norm(v - (v @ z) * z)
        assert miss < 1e-3, f"{name}: {frame}'s optical axis passes {miss * 1e3:.2f} mm from it"


@pytest.mark.parametrize("name", WITH_RANGE_FINDERS)
def test_the_robot_camera_does_not_see_the_beams(name):
    """MuJoCo draws a rangefinder's ray in a viewer; a camera sees no laser beam in the air."""
    from marionette._core import sim

    desc = robots.robot(name)
    scene = sim.MjScene(str(desc.mjcf))
    scene.reset_keyframe("reference")
    for c in desc.cameras:
        rgb, _ = sim.RgbdRenderer(scene, c.name, c.width, c.height).render(scene)
        ray = (rgb[..., 0] > 200) & (rgb[..., 1] > 200) & (rgb[..., 2] < 90)  # MuJoCo's yellow
        assert ray.sum() == 0, f"{name}: {c.name} shows {ray.sum()} pixels of beam"
