"""marionette-controller --encoder-offsets: the calibrated encoders of an arm whose simulated
encoders read 7° high (thesis 000 ch. 4) give the controller the true angle, and a malformed
calibration is refused before anything moves."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pytest

from marionette import channels, lcmt_robot_state, robots
from marionette.control.client import configuration_from_state
from marionette.scenarios.perturbations import scene_with_joint_offsets

OFFSET = math.radians(7.0)


@pytest.mark.slow
def test_calibrated_encoders_read_the_true_angle_and_the_robot_holds_still(
    run_controller, tmp_path
):
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    i = model.joints[model.getJointId("arm_left_1_joint")].idx_q
    scene = scene_with_joint_offsets(
        robots.robot("talos").mjcf, {"arm_left_1_joint": OFFSET}, tmp_path / "s.xml"
    )
    # Every state of each run by controller time: MuJoCo is deterministic and the held robot
    # moves the same in both runs (the hold acts on what the encoders read, offset included), so
    # at the same tick the two readings differ by the offset alone. The publisher samples the loop
    # on the wall clock, so the runs are paced in real time and every tick is published (1 kHz):
    # unpaced, a loaded machine samples two disjoint sets of ticks.
    readings: dict[str, dict[int, np.ndarray]] = {}
    for name, extra in (
        ("raw", ()),
        ("calibrated", ("--encoder-offsets", f"arm_left_1_joint={OFFSET:.9f}")),
    ):
        with run_controller(
            "--robot",
            "talos",
            "--scene",
            str(scene),
            "--speed",
            "1",
            "--state-rate",
            "1000",
            "--camera-rate",
            "0",
            *extra,
        ) as c:
            states: dict[int, np.ndarray] = {}
            c.bus.subscribe(
                channels.ROBOT_STATE,
                lcmt_robot_state,
                lambda m, states=states: states.setdefault(
                    m.utime, configuration_from_state(model, m)
                ),
            )
            c.wait_time(2.0)
            readings[name] = dict(states)
        first, last = min(states), max(states)
        assert np.abs(states[last][7:] - states[first][7:]).max() < 0.01, (
            f"{name}: the held robot moved"
        )  # settling: < 0.2°
    common = sorted(set(readings["raw"]) & set(readings["calibrated"]))
    assert common, "no controller tick seen in both runs"
    raw, calibrated = readings["raw"][common[-1]], readings["calibrated"][common[-1]]
    assert abs(raw[i] - calibrated[i] - OFFSET) < 1e-6
    others = np.r_[7:i, i + 1 : model.nq]
    assert np.abs(raw[others] - calibrated[others]).max() < 1e-3


def test_a_malformed_calibration_is_refused_with_the_reason(build_dir):
    binary = str(build_dir / "marionette-controller")
    for value, reason in (
        ("arm_left_1_joint=nan", "not joint=value"),
        ("arm_left_1_joint", "not joint=value"),
        ("no_such_joint=0.1", "no such 1-dof joint"),
    ):
        out = subprocess.run(
            [
                binary,
                "--robot",
                "talos",
                "--duration",
                "0.01",
                "--lcm-url",
                "memq://",
                "--camera-rate",
                "0",
                "--encoder-offsets",
                value,
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode != 0 and reason in out.stderr, (value, out.returncode, out.stderr)
