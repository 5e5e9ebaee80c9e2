"""marionette-controller at --speed 0 (simulated time) waits for a streamed reference instead of
outrunning it: a slow streamer never trips the reference watchdog, controller time never passes
the last sample of a running stream, and a streamer that is really gone still trips the watchdog
(after the loop's wall-clock wait); a command ends the wait at once."""

from __future__ import annotations

import re
import time

import numpy as np
import pinocchio as pin
import pytest

from marionette import channels, lcmt_robot_state, robots
from marionette.control.client import configuration_from_state, pose_to_vector
from marionette.control.spec import ControllerSpec, TaskSpec, reference_chunk
from marionette.lcm_bus import MessageLog

UR10 = ["--robot", "ur10", "--backend", "kinematic", "--camera-rate", "0", "--speed", "0"]
TIMEOUT_S = 0.05  # the controller's reference watchdog [s of controller time]
STARVED_WALL_S = 5.0  # the loop's wait for a starved stream (controller.cc kStarvedWallTimeout)


def _streaming(c):
    """Controller 1 (a streamed tool pose) running; returns (tool pose now, chunk maker)."""
    spec = ControllerSpec(
        1,
        "arm",
        [
            TaskSpec("tool", "se3", 0, frame="tool0", gain=1.0, streamed=True),
            TaskSpec("posture", "posture", 1, gain=1.0),
        ],
        max_switch_velocity_jump=0.05,
        reference_timeout=TIMEOUT_S,
    )
    c.send_spec(spec)
    c.wait(lambda c: c.status.active_controller_id == 1 and c.status.mode == "running", 20, "arm")
    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    data = model.createData()
    pin.framesForwardKinematics(model, data, configuration_from_state(model, c.state))
    X = data.oMf[model.getFrameId("tool0")]

    def chunk(start_us: int, n: int, sequence: int, last: bool = False):
        # the tool rising 1 cm/s from where it is, sample k at start_us + k ms
        values = np.array(
            [
                pose_to_vector(pin.SE3(X.rotation, X.translation + [0, 0, 1e-5 * k]))
                for k in range(n)
            ]
        )
        return reference_chunk(
            1,
            "tool",
            start_us,
            values,
            np.tile([0, 0, 0.01, 0, 0, 0], (n, 1)),
            last=last,
            sequence=sequence,
        )

    return chunk


@pytest.mark.slow
def test_a_slow_streamer_holds_the_unpaced_clock_without_tripping_the_watchdog(run_controller):
    with run_controller(*UR10, "--state-rate", "1000") as c:
        states = MessageLog(c.bus, channels.ROBOT_STATE, lcmt_robot_state)
        chunk = _streaming(c)
        t0 = c.utime() + 20_000
        n = 100  # 100 ms of controller time per chunk: ~10 ms of wall time unpaced
        for k in range(8):
            c.send_reference(chunk(t0 + k * n * 1000, n, k, last=k == 7))
            last_sample = t0 + ((k + 1) * n - 1) * 1000
            time.sleep(0.3)  # a streamer 30x slower than the clock
            if k < 7:
                # the clock waits at the last sample: never a tick past it
                assert max(m.utime for m in states.messages) <= last_sample, k
                assert c.status.mode == "running", c.status.mode_reason
        c.wait(lambda c: c.utime() > last_sample + 200_000, 10, "the clock after the end")
        assert c.status.mode == "running", c.status.mode_reason


@pytest.mark.slow
def test_a_streamer_gone_trips_the_watchdog_after_the_wait_and_a_command_ends_it(run_controller):
    with run_controller(*UR10, "--state-rate", "100") as c:
        chunk = _streaming(c)
        t0 = c.utime() + 20_000
        c.send_reference(chunk(t0, 100, 0))
        last_sample = t0 + 99_000
        c.wait(lambda c: c.utime() >= last_sample - 10_000, 10, "the end of the samples")
        wall0 = time.monotonic()
        c.wait(lambda c: c.status.mode == "holding", STARVED_WALL_S + 20, "the watchdog")
        waited = time.monotonic() - wall0
        assert "watchdog" in c.status.mode_reason, c.status.mode_reason
        assert STARVED_WALL_S - 0.5 <= waited <= STARVED_WALL_S + 10, waited
        # held as at real time: at the first tick the reference is older than its timeout
        stale_ms = float(re.search(r"stale for (\d+) ms", c.status.mode_reason).group(1))
        assert TIMEOUT_S * 1e3 <= stale_ms <= TIMEOUT_S * 1e3 + 2, c.status.mode_reason

    with run_controller(*UR10, "--state-rate", "100") as c:
        chunk = _streaming(c)
        t0 = c.utime() + 20_000
        c.send_reference(chunk(t0, 100, 0))
        c.wait(lambda c: c.utime() >= t0 + 90_000, 10, "the end of the samples")
        time.sleep(0.5)  # starved: the loop waits
        wall0 = time.monotonic()
        c.send_command("hold")
        c.wait(lambda c: c.status.mode == "holding", 10, "the hold")
        assert time.monotonic() - wall0 < 2.0
        assert "command" in c.status.mode_reason, c.status.mode_reason


@pytest.mark.slow
def test_a_stretch_re_sent_from_the_past_in_pieces_waits_for_its_last_piece(run_controller):
    """A supervisor correcting a streamed reference (visual servoing) re-sends what it had sent
    from where it last saw the clock, in pieces; a chunk replaces the stream's future from its
    start. Unpaced, the supervisor's view lagged the clock by 1.5 s, so its first piece ended the
    stream before the clock: the loop, seeing a chunk queued, ticked on and the watchdog held
    the robot before the next piece came (a plank-flip trial). The loop now judges what the
    chunks taken in cover, and waits for the next piece."""
    with run_controller(*UR10, "--state-rate", "1000") as c:
        chunk = _streaming(c)
        t0 = c.utime() + 20_000
        for k in range(4):  # 800 ms of samples
            c.send_reference(chunk(t0 + k * 200_000, 200, k))
        c.wait(lambda c: c.utime() >= t0 + 700_000, 10, "the clock in the last chunk")
        # The re-sent stretch: from 500 ms (behind the clock) in two pieces, the first ending at
        # 650 ms (behind it too), the second after a wall-clock pause.
        c.send_reference(chunk(t0 + 500_000, 150, 4))
        time.sleep(0.4)
        assert c.status.mode == "running", c.status.mode_reason
        c.send_reference(chunk(t0 + 650_000, 350, 5, last=True))
        c.wait(lambda c: c.utime() > t0 + 1_200_000, 10, "the clock after the end")
        assert c.status.mode == "running", c.status.mode_reason
