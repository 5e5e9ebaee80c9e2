"""ur10-box holds its box by friction alone: measured in the recorded demo run (the simulator's
contact forces on the jaws, the box's pose in the hand, the commands sent to the simulator)."""

from __future__ import annotations

import json

import lcm

from marionette import channels, lcmt_sim_command


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
