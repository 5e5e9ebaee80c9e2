"""`marionette demo drill --speed 2 --view` end to end (thesis 000 §6.3): MuJoCo controller on
the ur10_drill scene with the part displaced, the scene camera measured by `marionette perceive`,
alignment on R1/R2, interpolation of the other holes. The verdict is re-derived from the run's
files alone with independent code: the true part pose parsed from the scene.xml the controller
loaded, each hole from models/objects/part.yaml, the tool pose from the ROBOT_STATE recorded in
the LCM log at the hole's time, through drill_link and the gripper pose of robot.yaml (not the
demo's tip frame)."""

from __future__ import annotations

import re

import numpy as np
import pinocchio as pin
import pytest
import yaml

import marionette
from marionette import robots
from marionette.control.client import configuration_from_state
from tests_support import robot_states_at, run_demo


def _se3(xyz, xyzw) -> pin.SE3:
    x, y, z, w = xyzw
    return pin.SE3(pin.Quaternion(w, x, y, z).normalized().matrix(), np.array(xyz, dtype=float))


@pytest.mark.slow
def test_demo_drill_every_hole_within_0_2_mm_0_5_deg(tmp_path, build_dir, lcm_env):
    out, report = run_demo(
        "drill",
        tmp_path,
        lcm_env,
        speed=2,
        timeout_s=240,
        args=("--seed", "3", "--view"),
        files=(
            "report.md",
            "hole_errors.png",
            "spindle_R1.png",
            "spindle_R2.png",
            "run.lcmlog",
            "logs/viewer.log",
        ),
    )
    assert report["viewer_url"].startswith("http://")  # --view: the browser view was served

    # True part pose: the mocap body of the scene the controller ran.
    body = re.search(
        r'<body name="part" pos="([^"]+)" quat="([^"]+)" mocap="true">',
        (out / "scene.xml").read_text(),
    )
    w, x, y, z = (float(v) for v in body.group(2).split())
    X_WP = pin.SE3(
        pin.Quaternion(w, x, y, z).normalized().matrix(),
        np.array(body.group(1).split(), dtype=float),
    )
    part = yaml.safe_load((marionette.MODELS_DIR / "objects" / "part.yaml").read_text())
    holes = {h["name"]: _se3(h["pose"]["xyz"], h["pose"]["xyzw"]) for h in part["handles"]}
    scene = yaml.safe_load((marionette.MODELS_DIR / "scenes" / "ur10_drill.yaml").read_text())
    nominal = scene["objects"][0]["pose"]
    X_WP_nom = _se3(nominal["xyz"], nominal["xyzw"])
    # The perturbation matters: the offline program (nominal part) misses every hole by far more
    # than the tolerance.
    assert (
        min(
            np.linalg.norm((X_WP * H).translation - (X_WP_nom * H).translation)
            for H in holes.values()
        )
        > 0.005
    )

    gripper = next(
        g
        for g in yaml.safe_load((marionette.MODELS_DIR / "ur10" / "robot.yaml").read_text())[
            "grippers"
        ]
        if g["name"] == "ur10/drill"
    )
    X_link_tool = _se3(gripper["pose"]["xyz"], gripper["pose"]["xyzw"])
    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    data = model.createData()
    link = model.getFrameId(gripper["link"])
    states = robot_states_at(out / "run.lcmlog", {h["utime"] for h in report["holes"]})
    standoff = report["settings"]["standoff_m"]
    assert {h["hole"] for h in report["holes"]} == set(holes)  # every hole visited
    for row in report["holes"]:
        pin.framesForwardKinematics(
            model, data, configuration_from_state(model, states[row["utime"]])
        )
        X_tool = data.oMf[link] * X_link_tool
        X_hole = X_WP * holes[row["hole"]]
        axis = X_hole.rotation[:, 0]
        dp = np.linalg.norm(X_tool.translation - (X_hole.translation - standoff * axis))
        da = np.degrees(np.arccos(np.clip(X_tool.rotation[:, 0] @ axis, -1.0, 1.0)))
        assert dp <= 2e-4 and da <= 0.5, (row["hole"], dp, da)
        assert abs(dp - row["position_error_m"]) < 1e-6 and abs(da - row["angle_error_deg"]) < 1e-3


@pytest.mark.slow
def test_drill_without_camera_detects_that_the_sensor_cannot_see_r1(tmp_path, build_dir):
    """§6.3: "Whenever one of those steps cannot be performed, the robot should autonomously detect
    its failure". Going to R1 on the nominal model alone (the offline program), the displaced
    hole is not where the tool's sensors look for it: the demo stops with that reason, it does not
    drill blind."""
    import dataclasses

    from marionette.scenarios import SCENARIOS, RunOptions, ScenarioError
    from marionette.scenarios.drill import DrillSettings

    st = DrillSettings(camera=False)
    blind = dataclasses.replace(SCENARIOS["drill"], settings=st)
    with pytest.raises(
        ScenarioError,
        match=(
            r"part/R1: the tool's sensors cannot measure the hole "
            r"\((the skin within|the dark region|nothing dark).*an operator must locate it"
        ),
    ):
        blind.run(3, tmp_path, RunOptions(speed=2.0, log=lambda m: None))
