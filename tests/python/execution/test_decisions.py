"""The supervisor's decision function: decisions are a function of the messages fed,
taken at the tick of the last status, and re-taken identically by the offline replay."""

from __future__ import annotations

import pytest

from marionette import lcmt_controller_status, lcmt_supervisor_decision, lcmt_supervisor_event
from marionette.control.spec import HOLD_CONTROLLER_ID
from marionette.execution.decisions import (
    EVENT,
    STATUS,
    Decision,
    DecisionMachine,
    replay_decisions,
)

CID = 7
THRESHOLDS = {"arm": 0.01, "posture": 0.05}


def status(
    utime: int,
    active: int = CID,
    errors: dict[str, float] | None = None,
    mode: str = "running",
    reason: str = "",
    switch: str = "",
    rejection: str = "",
) -> lcmt_controller_status:
    st = lcmt_controller_status()
    st.utime, st.tick, st.mode, st.mode_reason = utime, utime // 1000, mode, reason
    st.active_controller_id = active
    errors = errors if errors is not None else {"arm": 1e-3, "posture": 1e-3}
    st.num_tasks, st.task_name, st.task_error_norm = (
        len(errors),
        list(errors),
        list(errors.values()),
    )
    st.last_switch_result, st.last_rejection = switch, rejection
    return st


def event(name: str, value: float = 0.0, utime: int = 0) -> lcmt_supervisor_event:
    ev = lcmt_supervisor_event()
    ev.utime, ev.name, ev.source, ev.detail, ev.value = utime, name, "cli", "", value
    return ev


def run_step(machine: DecisionMachine, inputs, start=200_000, end=1_000_000) -> list[Decision]:
    """A step: begin, then the inputs; the reference starts right after the swap is accepted."""
    out = [machine.begin_step(0, "t0", CID, THRESHOLDS, 300_000)]
    for channel, msg in inputs:
        for d in machine.feed(channel, msg):
            out.append(d)
            if d.event == "switch_accepted":
                out.append(machine.start_reference(start, end))
    return out


def test_nominal_step_decisions_at_status_ticks():
    inputs = [(STATUS, status(t, active=3)) for t in (10_000, 20_000)]  # old controller
    inputs += [(STATUS, status(30_000))]  # swap seen
    inputs += [
        (STATUS, status(t, errors={"arm": 0.5, "posture": 0.0}))
        for t in range(40_000, 1_000_000, 10_000)
    ]
    inputs += [
        (STATUS, status(1_000_000, errors={"arm": 0.02, "posture": 0.0}))
    ]  # end reached, not converged
    inputs += [(STATUS, status(1_010_000, errors={"arm": 0.02, "posture": 0.0}))]
    inputs += [(STATUS, status(1_020_000, errors={"arm": 0.009, "posture": 0.04}))]
    ds = run_step(DecisionMachine(), inputs)
    assert [(d.event, d.utime, d.to_status) for d in ds] == [
        ("step_started", 0, "waiting_start_check"),
        ("switch_accepted", 30_000, "accepted"),
        ("reference_started", 30_000, "running"),
        # the first status at or after the last sample ends the reference ...
        ("end_of_reference", 1_000_000, "waiting_end_check"),
        # ... and the end check reads only the statuses after it, until every error <= threshold
        ("end_check_passed", 1_020_000, "ended"),
    ]
    assert ds[-1].inputs == {"error:arm": 0.009, "error:posture": 0.04, "end_utime": 1_000_000.0}


def test_end_check_fails_after_the_converge_timeout():
    inputs = [(STATUS, status(30_000))]
    inputs += [
        (STATUS, status(t, errors={"arm": 0.02, "posture": 0.0}))
        for t in range(1_000_000, 1_500_000, 100_000)
    ]
    ds = run_step(DecisionMachine(), inputs)
    assert ds[-1].event == "end_check_failed" and ds[-1].to_status == "failed"
    # 1.0 s end + 0.3 s timeout: the first status strictly after 1.3 s decides
    assert ds[-1].utime == 1_300_000 + 100_000 and "arm" in ds[-1].detail


def test_refused_switch_and_rejected_spec_fail_the_step():
    m = DecisionMachine()
    accepted_text = run_step(m, [(STATUS, status(10_000, active=3, switch=f"accepted (id {CID})"))])
    assert [d.event for d in accepted_text] == [
        "step_started"
    ]  # waits for the snapshot's active id
    ds = run_step(
        DecisionMachine(), [(STATUS, status(10_000, active=3, switch=f"refused (id {CID}): jump"))]
    )
    assert ds[-1].event == "switch_refused" and ds[-1].to_status == "failed"
    ds = run_step(
        DecisionMachine(), [(STATUS, status(10_000, active=3, rejection=f"bad frame (id {CID})"))]
    )
    assert ds[-1].event == "spec_rejected"
    # The controller counts a refused switch as a rejection too, and a status can carry that
    # before the switch result (seen in a fresh-clone CI run): still a refused switch.
    refusal = (
        f"CONTROLLER_SPEC: refused controller 'step0' (id {CID}): command jump 3.2 rad/s > 0.1"
    )
    ds = run_step(DecisionMachine(), [(STATUS, status(10_000, active=3, rejection=refusal))])
    assert ds[-1].event == "switch_refused" and ds[-1].to_status == "failed"


def test_force_event_applies_at_the_last_status_tick_and_watchdog_fails():
    m = DecisionMachine()
    ds = run_step(
        m,
        [
            (STATUS, status(30_000)),
            (STATUS, status(50_000)),
            (EVENT, event("force_threshold", 5.2, 1)),
        ],
    )
    assert (ds[-1].event, ds[-1].utime, ds[-1].input_utime) == ("reference_stopped", 50_000, 1)
    ds = run_step(
        DecisionMachine(),
        [
            (STATUS, status(30_000)),
            (STATUS, status(60_000, mode="holding", reason="watchdog: stale")),
        ],
    )
    assert (ds[-1].event, ds[-1].utime) == ("reference_starved", 60_000)
    # the controller's hold controller replaced this step's one (time budget): failed, not waiting
    ds = run_step(
        DecisionMachine(),
        [
            (STATUS, status(30_000)),
            (
                STATUS,
                status(
                    70_000,
                    active=HOLD_CONTROLLER_ID,
                    mode="holding",
                    reason="time budget: ...; the hold (posture) controller",
                ),
            ),
        ],
    )
    assert (ds[-1].event, ds[-1].utime, ds[-1].to_status) == (
        "controller_holding",
        70_000,
        "failed",
    )
    # once every chunk is sent, a force event still cuts the reference (a chunk redefines the
    # stream from its first sample), but only the first one of the step
    m = DecisionMachine()
    run_step(m, [(STATUS, status(30_000))])
    m.reference_end(1_000_000, True)
    assert [d.event for d in m.feed(EVENT, event("force_threshold", 5.0))] == ["reference_stopped"]
    assert m.feed(EVENT, event("force_threshold", 6.0)) == []


def test_decision_round_trips_through_lcm():
    d = DecisionMachine().begin_step(3, "grasp box", CID, THRESHOLDS, 300_000)
    msg = lcmt_supervisor_decision.decode(d.to_lcm(4, "ur10_box").encode())
    assert msg.seq == 4 and Decision.from_lcm(msg) == d


def _recorded_run():
    inputs = [(STATUS, status(t, active=3)) for t in (10_000, 20_000)]
    inputs += [
        (STATUS, status(t, errors={"arm": 0.5 if t < 1_000_000 else 0.0, "posture": 0.0}))
        for t in range(30_000, 1_100_000, 10_000)
    ]
    return run_step(DecisionMachine(), inputs), inputs


def test_replay_retakes_the_recorded_decisions():
    recorded, inputs = _recorded_run()
    r = replay_decisions(recorded, inputs)
    assert r.ok, r.first_divergence
    assert r.replayed == r.recorded == 5 and r.statuses == len(inputs)


def test_replay_names_the_first_diverging_tick():
    recorded, inputs = _recorded_run()
    # One status lost on the way: the end check passes 10 ms later than recorded.
    lost = [(c, m) for c, m in inputs if m.utime != 1_010_000]
    r = replay_decisions(recorded, lost)
    assert not r.ok
    assert (
        r.first_divergence.startswith("decision 4 at tick 1010000 us")
        and "end_check_passed" in r.first_divergence
    )
    assert "replayed at tick 1020000" in r.first_divergence


def test_feed_rejects_an_unknown_channel():
    with pytest.raises(ValueError, match="CONTROLLER_STATUS"):
        DecisionMachine().feed("ROBOT_STATE", object())
