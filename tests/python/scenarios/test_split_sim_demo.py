"""`marionette demo ur10-box --split-sim`: the whole stack run as it would run on a robot —
marionette-sim (the MuJoCo scene, a driver process: DRIVER_STATE out, DRIVER_COMMAND in) and
marionette-controller --backend driver, with the supervisor and the logger — passes the
scenario's own criteria, says in its report where the robot was simulated, and its run replays
from the robot states the controller took (run_demo replays it)."""

from __future__ import annotations

import pytest

from tests_support import run_demo


@pytest.mark.slow
def test_ur10_box_runs_split_as_on_a_robot(tmp_path, lcm_env):
    run, report = run_demo(
        "ur10-box",
        tmp_path,
        lcm_env,
        speed=0.0,
        timeout_s=600.0,
        files=("run.lcmlog", "controller-journal.lcmlog", "logs/sim.log"),
        args=("--split-sim",),
    )
    assert report["simulator"].startswith("marionette-sim"), report["simulator"]
    assert "on driver backend" in (run / "logs" / "controller.log").read_text()
