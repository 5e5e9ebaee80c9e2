"""TALOS' arm encoder offsets from its wrist rings seen by the head camera (thesis 000 ch. 4.2):
views planned on the nominal model, images rendered by MuJoCo of the robot whose left encoders
read 7° high at the shoulder and 4° low at the wrist, tags detected by ViSP."""

from __future__ import annotations

import math

import pytest

import marionette
from marionette import robots
from marionette.perception.arm_calibration import (
    CalibrationError,
    arm_joints,
    calibrate_arm,
    calibration_frames,
)
from marionette.scenarios.perturbations import scene_with_joint_offsets

TRUE = {"arm_left_1_joint": math.radians(7.0), "arm_left_7_joint": math.radians(-4.0)}


@pytest.fixture(scope="module")
def offset_scene(tmp_path_factory):
    return scene_with_joint_offsets(
        marionette.MODELS_DIR / "scenes" / "talos_plank.xml",
        TRUE,
        tmp_path_factory.mktemp("scene") / "scene.xml",
    )


@pytest.mark.slow
@pytest.mark.parametrize("side", ["left", "right"])
def test_every_offset_of_the_arm_within_0p3deg(offset_scene, side):
    cal = calibrate_arm(offset_scene, side, "talos", log=lambda line: None)
    assert cal.views_used >= 5, cal.summary()  # the others: ring hidden by the hand or the plank
    found = cal.encoder_offsets()
    error_deg = {j: math.degrees(found[j] - TRUE.get(j, 0.0)) for j in arm_joints("talos", side)}
    assert max(abs(e) for e in error_deg.values()) < 0.3, error_deg
    summary = cal.summary()
    assert summary["residual_position_mm"] < 3.0 and summary["residual_rotation_deg"] < 1.0, summary


@pytest.mark.slow
def test_the_command_prints_the_controller_option(offset_scene, tmp_path, capsys):
    from marionette.cli import main

    argv = ["calibrate", "arm-encoders", "--scene", str(offset_scene), "--robot", "talos"]
    assert main([*argv, "--side", "left"]) == 0
    out = __import__("json").loads(capsys.readouterr().out)
    option = dict(item.split("=") for item in out["controller_option"].split()[1].split(","))
    assert abs(math.degrees(float(option["arm_left_1_joint"])) - 7.0) < 0.3
    with pytest.raises(SystemExit, match="no scene file"):
        main(["calibrate", "arm-encoders", "--scene", str(tmp_path / "missing.xml")])


@pytest.mark.parametrize("robot", robots.robot_names())
def test_a_robot_without_calibration_frames_is_told_which_file_lacks_them(robot):
    desc = robots.robot(robot)
    if desc.calibration_base_frame is None or desc.camera_frame is None:
        with pytest.raises(CalibrationError, match=f"{desc.semantics}: .*(base_frame|camera)"):
            calibration_frames(robot)
    else:
        assert calibration_frames(robot) == (desc.calibration_base_frame, desc.camera_frame)
