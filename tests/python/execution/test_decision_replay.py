"""`marionette replay LOG --supervisor` on a recorded ur10-box run: the decisions
re-taken offline from the recorded statuses are the recorded ones, tick for tick; a log whose
inputs were altered diverges at the first tick the alteration changes. The record replayed is the
supervisor's own journal beside the run's LCM log, and the decisions the network logger caught
are the journal's."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import lcm
from marionette import channels, lcmt_controller_status, lcmt_supervisor_decision
from marionette.execution.decision_replay import (
    decision_record,
    read_decision_log,
    replay_supervisor,
)
from marionette.execution.supervisor import JOURNAL_NAME


@pytest.mark.slow
def test_recorded_ur10_box_decisions_are_retaken_identically(ur10_box_run):
    log = ur10_box_run / "run.lcmlog"
    proc = subprocess.run(
        [sys.executable, "-m", "marionette.cli", "replay", str(log), "--supervisor"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "IDENTICAL" in proc.stdout
    journal = decision_record(log)
    assert journal == ur10_box_run / JOURNAL_NAME and str(journal) in proc.stdout
    recorded, _ = read_decision_log(journal)
    # What the run's logger caught of them over UDP is the journal's, message for message.
    caught = [
        lcmt_supervisor_decision.decode(ev.data)
        for ev in lcm.EventLog(str(log), "r")
        if ev.channel == channels.SUPERVISOR_DECISION
    ]
    in_journal = {
        m.seq: m.encode()
        for m in (
            lcmt_supervisor_decision.decode(ev.data)
            for ev in lcm.EventLog(str(journal), "r")
            if ev.channel == channels.SUPERVISOR_DECISION
        )
    }
    assert sorted(in_journal) == list(range(len(recorded)))
    assert caught and all(in_journal[m.seq] == m.encode() for m in caught)
    report = json.loads((ur10_box_run / "report.json").read_text())
    steps = len(report["steps"])
    # Independent reference: the report's per-step records, written by the live supervisor.
    events = [d.event for d in recorded]
    assert (
        events.count("switch_accepted") == events.count("end_check_passed") == steps >= 3
    )  # every step of the plan (at least reach, carry, release) switched to and ended
    accepted = [d for d in recorded if d.event == "switch_accepted"]
    assert [int(d.inputs["active_controller_id"]) for d in accepted] == [
        s["controller_id"] for s in report["steps"]
    ]
    assert all(d.utime > 0 for d in accepted)
    ticks = [d.utime for d in recorded]
    assert ticks == sorted(ticks)


def test_altered_inputs_diverge_at_the_first_changed_decision(ur10_box_run, tmp_path):
    src = decision_record(ur10_box_run / "run.lcmlog")
    recorded, _ = read_decision_log(src)
    target = next(d for d in recorded if d.event == "end_check_passed")
    # Rewrite the status that passed the first end check with a task error above every threshold.
    dst = tmp_path / "altered.lcmlog"
    out = lcm.EventLog(str(dst), "w", overwrite=True)
    for ev in lcm.EventLog(str(src), "r"):
        data = ev.data
        if ev.channel == channels.CONTROLLER_STATUS:
            st = lcmt_controller_status.decode(data)
            if st.utime == target.utime:
                st.task_error_norm = [1.0] * st.num_tasks
                data = st.encode()
        out.write_event(ev.timestamp, ev.channel, data)
    out.close()
    r = replay_supervisor(dst)
    assert not r.ok
    assert r.first_divergence.startswith(
        f"decision {recorded.index(target)} at tick {target.utime} us"
    )
    assert "recorded end_check_passed" in r.first_divergence
