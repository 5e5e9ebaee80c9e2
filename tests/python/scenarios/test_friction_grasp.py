"""ur10-box holds its box by friction alone: measured in the recorded demo run (the simulator's
contact forces on the jaws, the box's pose in the hand, the commands sent to the simulator), and a
grasp that closes on nothing stops the arm."""

from __future__ import annotations

import json

import numpy as np
import pytest

import lcm
from marionette import channels, lcmt_sim_command
from tests_support import demo_process


def test_the_box_is_held_by_friction_without_a_weld(ur10_box_run):
    report = json.loads((ur10_box_run / "report.json").read_text())
    assert report["success"], report.get("criteria")
    held = [h for g in report["grip"]["grippers"].values() for h in g["held"]]
    assert held
    for h in held:
        assert abs(h["contact_median_n"] - 5.0) <= 1.0, h
        # Over the hold (lift, carry at up to 1 rad/s per joint): the box stays in the hand.
        assert h["object_motion_mm"] < 1.0 and h["object_rotation_deg"] < 1.0, h
    log = lcm.EventLog(str(ur10_box_run / "run.lcmlog"), "r")
    commands = [
        lcmt_sim_command.decode(e.data).command for e in log if e.channel == channels.SIM_COMMAND
    ]
    assert "attach" not in commands, commands


@pytest.mark.slow
def test_a_grasp_that_closes_on_nothing_stops_the_arm_before_it_lifts(tmp_path, lcm_env):
    """The box moved 20 cm after planning, the plan played open loop: the fingers close on air.
    The grip monitor sees them reach the closed end from the encoder, the supervisor fails the
    step after the grasp while its arm still waits for the grip, and the robot holds: the box
    has not moved, the arm never lifted."""
    proc = demo_process(
        "ur10-box",
        "--speed",
        "0",
        "--perturb",
        "displacement_m=0.25",
        out=str(tmp_path),
        timeout_s=600,
        env=lcm_env,
    )
    assert proc.returncode != 0, proc.stdout
    (run,) = tmp_path.glob("ur10-box-*")
    report = json.loads((run / "report.json").read_text())
    assert not report["success"]
    (lost,) = report["grasps_lost"]
    assert lost["gripper"] == "ur10/gripper" and "holds nothing" in lost["detail"]
    steps = report["steps"]
    failed = [s for s in steps if s["result"] != "ok"]
    assert failed and failed[0]["result"].startswith("grasp_lost"), failed
    grasp = next(i for i, s in enumerate(steps) if s["kind"] == "grasp")
    assert failed[0]["index"] == steps[grasp]["index"] + 1
    # The box is where the perturbation put it: its distance to the goal is the plan's 0.5 m
    # move (planning/problems/ur10_box.yaml: y 0.25 -> -0.25) plus the drawn displacement.
    dx, dy, _ = report["perturbation"]["displacement"]
    untouched = float(np.hypot(dx, 0.25 + dy - (-0.25)))
    assert report["criteria"]["object_position_error_m"] == pytest.approx(untouched, abs=2e-3)


@pytest.mark.slow
def test_friction_grasps_with_a_gripper_that_cannot_hold_are_refused_in_one_line(tmp_path, lcm_env):
    """The UR5's suction cup has no fingers: a scenario that asks it to hold by friction is
    refused before anything moves, naming the gripper and what to change."""
    from marionette.scenarios.declarations import BUNDLED_DIR

    decl = (
        (BUNDLED_DIR / "ur5-cube.yaml")
        .read_text()
        .replace("name: ur5-cube", "name: ur5-cube-friction")
    )
    (tmp_path / "ur5-cube-friction.yaml").write_text(
        decl + "gripper_admittance: true\nfriction_grasps: true\n"
    )
    proc = demo_process(
        "ur5-cube-friction",
        "--speed",
        "0",
        out=str(tmp_path / "out"),
        timeout_s=300,
        env={**lcm_env, "MARIONETTE_SCENARIO_PATH": str(tmp_path)},
    )
    assert proc.returncode != 0
    errors = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and "gripper ur5/gripper cannot hold by friction" in errors[0], (
        proc.stderr
    )
    assert "Traceback" not in proc.stdout + proc.stderr


def _coulomb_friction_limit() -> float:
    """The friction coefficient below which ur10-box's squeeze cannot hold its box against
    gravity: m g = 2 mu F (two jaws, F each: the admittance's force target)."""
    import xml.etree.ElementTree as ET

    import marionette
    from marionette import _core

    scene = ET.parse(marionette.MODELS_DIR / "scenes" / "ur10_box.xml").getroot()
    box = next(b for b in scene.iter("body") if b.get("name") == "box")
    mass = float(box.find("inertial").get("mass"))
    return mass * 9.81 / (2.0 * _core.gripper_admittance_defaults()["force_target"])


@pytest.mark.slow
@pytest.mark.parametrize("factor", [0.75, 1.7])
def test_coulomb_decides_whether_a_box_gone_slippery_stays_in_the_fingers(
    tmp_path, lcm_env, factor
):
    """Once the grip has settled in the carry, the box's friction drops to ``factor`` times the
    Coulomb limit m g / (2 F). Below it the box slides out of the fingers: the grip monitor sees
    them close on nothing and the trial fails with the grasp lost; above it the box stays in the
    hand and is placed."""
    mu = factor * _coulomb_friction_limit()
    proc = demo_process(
        "ur10-box",
        "--speed",
        "0",
        "--perturb",
        f"carry_friction={mu:.4f}",
        out=str(tmp_path),
        timeout_s=600,
        env=lcm_env,
    )
    (run,) = tmp_path.glob("ur10-box-*")
    report = json.loads((run / "report.json").read_text())
    assert f"friction set to {mu:.4g}" in proc.stdout, proc.stdout
    assert f"friction set to {mu:.4g} once its grip settled" in (run / "report.md").read_text()
    if factor < 1.0:
        assert proc.returncode != 0 and not report["success"]
        (lost,) = report["grasps_lost"]
        assert "holds nothing" in lost["detail"], lost
    else:
        assert proc.returncode == 0 and report["success"], report.get("criteria")
        held = [h for g in report["grip"]["grippers"].values() for h in g["held"]]
        assert held and all(h["object_motion_mm"] < 5.0 for h in held), held
