"""Force-threshold events (thesis 000 §3.2.4.3 eq. 3.11-3.13, §3.2.5.2): the detector's
filter against the continuous first-order step response (exact at every sample, even at an
irregular state rate) and the tick it fires at against the closed-form crossing time; then the
event on the bus against the real controller and supervisor: the reference is cut at the event's
controller tick (plus the streamer's 20 ms lead and the loop's latency), the step still passes its
end check and the FSM goes on to `done`."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from marionette import channels, lcmt_robot_state
from marionette.execution.force_event import ForceEventDetector, ForceEventNode
from marionette.execution.supervisor import Supervisor, SupervisorOptions
from tests_support import controller_running


def _state(utime: int, effort: float) -> lcmt_robot_state:
    s = lcmt_robot_state()
    s.utime, s.robot_name = utime, "talos"
    s.joint_name = ["arm_right_7_joint", "gripper_right_joint"]
    s.joint_position = [0.0, -0.5]
    s.joint_velocity = [0.0, 0.0]
    s.joint_effort = [3.0, effort]
    s.num_joints = 2
    return s


def test_filter_is_exact_and_fires_at_the_closed_form_crossing():
    # A grip of 0.5 N m closing (s = -1) at d = 0.1 m is f = 5 N (eq. 3.13); y(t) = 5 (1 - e^{-2π 5
    # t}) crosses 4 N at t* = -ln(1 - 4/5) / (2π 5) = 51.2 ms.
    det = ForceEventDetector("gripper_right_joint", threshold=4.0)
    rng = np.random.default_rng(3)
    assert det.feed(_state(1_000_000, 0.0)) is None  # primes at 0 N
    t_star = -math.log(1.0 - 4.0 / 5.0) / (2.0 * math.pi * 5.0)
    t_us, fired_at = 0, None
    while t_us < 200_000:
        t_us += int(rng.integers(500, 3000))  # irregular state period 0.5-3 ms
        value = det.feed(_state(1_000_000 + t_us, -0.5))
        assert det.filtered == pytest.approx(
            5.0 * (1.0 - math.exp(-2.0 * math.pi * 5.0 * t_us * 1e-6)), abs=1e-9
        )
        if value is not None:
            assert fired_at is None, "fires once"
            fired_at = t_us
    assert fired_at is not None
    assert t_star * 1e6 <= fired_at < t_star * 1e6 + 3000  # the first sample past t*


def test_detector_rejects_bad_input_with_the_reason():
    with pytest.raises(ValueError, match="closing_direction must be"):
        ForceEventDetector("gripper_right_joint", 4.0, closing_direction=0.0)
    with pytest.raises(KeyError, match="joint 'nope' not in the robot state"):
        ForceEventDetector("nope", 4.0).feed(_state(0, 0.0))


KINEMATIC = (
    "--robot",
    "ur10",
    "--backend",
    "kinematic",
    "--speed",
    "4",
    "--camera-rate",
    "0",
    "--status-rate",
    "100",
)


def _run_with_contact(build_dir, lcm_url, tmp_path, ur10_box, at_fraction: float):
    """The ur10-box plan's first step (from the home posture the controller starts in: 17.7 s at
    0.5 rad/s), with the force detector on the live
    ROBOT_STATE. The kinematic backend measures no effort, so the effort a contact would add
    (10 N at the joint's 1 m lever, s = -1) is written into the states the detector reads from
    ``at_fraction`` of the first step on: what runs for real is the path from a state's tick to
    the event, the supervisor, the streamer and the controller's reference stream."""
    with controller_running(build_dir, lcm_url, tmp_path / "logs", *KINEMATIC) as c:
        first = ur10_box.steps[0]
        steps, specs = [first], [ur10_box.specs[first.index]]
        # 0.5 rad/s: the first step lasts longer than the supervisor's 4 s look-ahead.
        sup = Supervisor(
            c,
            steps,
            specs,
            ur10_box.robot_map,
            SupervisorOptions(simulated_grasps=False, max_joint_velocity=0.5),
            "ur10_box",
        )
        node = ForceEventNode(
            c.bus, ForceEventDetector("shoulder_lift_joint", threshold=4.0, lever_arm=1.0)
        )
        c.bus.lcm.unsubscribe(node._subscription)  # the node reads the states through `contact`
        start = {}

        def contact(state):
            traj = sup.trajectories.get(first.index)
            if sup.step_index == first.index and sup.status == "running" and "t0" not in start:
                start["t0"] = int(state.utime)
            if "t0" in start and int(state.utime) - start["t0"] > at_fraction * traj.duration * 1e6:
                effort = list(state.joint_effort)
                effort[list(state.joint_name).index("shoulder_lift_joint")] = -10.0
                state.joint_effort = effort
            node._on_state(state)

        c.bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, contact)
        out = {}
        runner = threading.Thread(target=lambda: out.setdefault("result", sup.run()))
        runner.start()
        runner.join(timeout=180.0)
        return out["result"], node


def _check_cut(result, node):
    assert result.success and result.state == "done", result.reason
    assert len(node.events) == 1
    event_utime, value = node.events[0]
    assert value > 4.0
    record = result.records[0]
    assert "force_threshold" in record.events and record.result == "ok"
    # Cut at the event: the last reference sample is the streamer's 20 ms lead after the event's
    # tick, plus the supervisor's reaction (controller time at 4x real time; loose bound).
    cut = record.utime_reference_end - event_utime
    print(f"reference cut {cut / 1e3:.1f} ms after the event's tick")
    assert 20_000 <= cut <= 20_000 + 500_000, cut
    # The FSM went on: the step ended by its end check (errors converged on the held sample).
    assert record.utime_end > record.utime_reference_end


@pytest.mark.slow
def test_force_event_cuts_the_reference_at_its_tick_and_the_fsm_goes_on(
    build_dir, lcm_url, tmp_path, ur10_box
):
    """Event at 40 % of a step: its reference is still being streamed."""
    _check_cut(*_run_with_contact(build_dir, lcm_url, tmp_path, ur10_box, 0.4))


@pytest.mark.slow
def test_force_event_in_the_last_lookahead_window_cuts_the_reference(
    build_dir, lcm_url, tmp_path, ur10_box
):
    """Event at 90 % of the step: everything was already streamed; it must still cut."""
    _check_cut(*_run_with_contact(build_dir, lcm_url, tmp_path, ur10_box, 0.9))
