"""A supervisor killed mid-carry (`marionette supervise` of the UR10 box plan, SIGKILL): the
controller holds the robot within its supervisor timeout, the box stays in the gripper; a new
`marionette supervise` estimates where the plan stands, skips the steps done, and finishes."""

from __future__ import annotations

import re
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from marionette import channels, lcmt_supervisor_state
from marionette.control.client import ControllerClient
from marionette.lcm_bus import MessageLog
from marionette.processes import ProcessGroup
from marionette.scenarios import SCENARIOS
from marionette.scenarios.plan_cache import plan_folder

pytestmark = pytest.mark.slow


def test_a_supervisor_killed_mid_carry_holds_and_a_new_one_finishes(
    ur10_box, plan_cache, build_dir, lcm_url, tmp_path
):
    p = ur10_box
    scenario = SCENARIOS["ur10-box"]
    plan_json = plan_folder(Path(scenario.problem), scenario.seed, plan_cache) / "plan.json"
    assert plan_json.exists()
    carry = next(s for s in p.steps if s.transition.endswith("_34"))
    supervise = [sys.executable, "-m", "marionette.cli", "supervise", str(plan_json)]
    supervise += ["--lcm-url", lcm_url, "--gripper-admittance"]
    with ProcessGroup(lcm_url, tmp_path / "logs") as group, ControllerClient(lcm_url) as c:
        group.start(
            "controller",
            [build_dir / "marionette-controller", "--lcm-url", lcm_url, "--robot", "ur10"]
            + ["--scene", str(scenario.scene), "--speed", "2", "--camera-rate", "0"],
        )
        c.wait_ready(60.0, processes=group)
        q0 = np.array(p.plan.doc["problem"]["q_init"])
        for name in p.robot_map.objects:  # the objects where the planner started
            c.move_object(name, p.robot_map.object_pose(q0, name))
        c.wait_time(0.5)
        states = MessageLog(c.bus, channels.SUPERVISOR_STATE, lcmt_supervisor_state)
        first = group.start("supervise1", [*supervise, "--specs", tmp_path / "c1.yaml"])
        c.wait(
            lambda c: (
                states.latest() is not None
                and states.latest().step_index == carry.index
                and states.latest().status == "running"
            ),
            300.0,
            "the carry",
        )
        c.wait_time(2.0)  # well into it, the box in the air
        first.popen.send_signal(signal.SIGKILL)
        first.popen.wait(10)
        c.wait(lambda c: c.status.mode == "holding", 5.0, "the hold")
        assert c.status.mode_reason.startswith("supervisor exited"), c.status.mode_reason
        assert f"process {first.popen.pid} " in c.status.mode_reason, c.status.mode_reason
        held = c.object_pose("box").translation.copy()
        c.wait_time(2.0)
        moved = np.linalg.norm(c.object_pose("box").translation - held)
        assert moved < 0.02, f"the box moved {moved:.3f} m after the hold"
        assert held[2] > p.robot_map.object_pose(q0, "box").translation[2] + 0.02  # still lifted

        second = group.start("supervise2", [*supervise, "--specs", tmp_path / "c2.yaml"])
        assert second.popen.wait(600) == 0, second.log_tail(40)
        log = second.log_path.read_text()
        start = int(re.search(r"starting at step (\d+)", log).group(1))
        assert start >= carry.index, log  # the steps done are skipped
        assert "supervisor: done" in log, log
