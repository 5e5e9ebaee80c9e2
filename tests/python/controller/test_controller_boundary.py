"""marionette-controller's boundary: absurd but finite values and unknown names refused with
their reason; signed commands (Python signs, C++ verifies: unsigned, altered, replayed, moved,
stale and foreign messages refused and counted); a supervisor killed mid-motion makes it hold —
at once on the same machine (its process is watched), within its --supervisor-timeout from
another — and a new one resumes."""

from __future__ import annotations

import re
import secrets
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

import lcm
from marionette import (
    channels,
    lcmt_command,
    lcmt_controller_journal,
    lcmt_controller_spec,
    lcmt_dg_request,
    lcmt_robot_command,
    lcmt_task_reference,
)
from marionette.control.introspection import rejections_by_channel
from marionette.control.replay_cli import replay_controller
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.lcm_bus import HEARTBEAT_HANG_S, LcmBus, MessageLog, logger_command
from marionette.lcm_signing import Signer, load_key
from tests_support import controller_running, wait_for_line

UR10 = ["--robot", "ur10", "--backend", "kinematic", "--camera-rate", "0", "--status-rate", "100"]


def _counts(status) -> dict[str, int]:
    return {
        f"{channel}: {reason}": n
        for channel, reasons in rejections_by_channel(status).items()
        for reason, n in reasons.items()
    }


def _spec(controller_id: int, **fields) -> lcmt_controller_spec:
    """A valid posture spec as raw LCM (the Python ControllerSpec refuses absurd values itself),
    then ``fields`` overwritten: "task.NAME" for the task's."""
    msg = ControllerSpec(controller_id, "raw", [TaskSpec("posture", "posture", 0)]).to_lcm()
    for name, value in fields.items():
        target = msg.tasks[0] if name.startswith("task.") else msg
        setattr(target, name.removeprefix("task."), value)
    return msg


@pytest.mark.slow
def test_absurd_values_and_unknown_names_are_refused_with_their_reason(
    build_dir, lcm_url, tmp_path
):
    with controller_running(build_dir, lcm_url, tmp_path / "logs", *UR10) as c:
        c.wait_time(0.1)
        q0 = list(c.state.joint_position)
        now = c.utime()
        chunk = lcmt_task_reference()
        chunk.task_name, chunk.controller_id, chunk.dt_us = "posture", 1, 1000
        request = lcmt_dg_request()
        request.command, request.num_values, request.value = "set", 1, [1.0]
        huge = bytearray(request.encode())
        struct.pack_into(">i", huge, 8 + 8 + 8 + 5 + 8 + 4, 1 << 27)  # num_values = 2^27
        command = lcmt_command()
        command.command, command.utime = "resume", -5
        sent = [
            (channels.CONTROLLER_SPEC, _spec(1, **{"task.gain": 1e300}), "out of range"),
            (channels.CONTROLLER_SPEC, _spec(2, reference_timeout=1e300), "out of range"),
            (channels.CONTROLLER_SPEC, _spec(3, max_switch_velocity_jump=1e300), "out of range"),
            (channels.CONTROLLER_SPEC, _spec(-7), "out of range"),
            (channels.CONTROLLER_SPEC, _spec(5, **{"task.priority": -1}), "out of range"),
            (
                channels.CONTROLLER_SPEC,
                _spec(6, **{"task.reference_channel": "NO_SUCH_CHANNEL"}),
                "invalid spec",
            ),
            (channels.COMMAND, command, "out of range"),
            (channels.DG_REQUEST, bytes(huge), "over maximum"),
        ]
        for stamp in (-1, (1 << 63) - 1, now + 60_000_000, -(1 << 62)):
            chunk.utime = stamp
            sent.append((channels.TASK_REFERENCE, chunk.encode(), "time out of range"))
        for channel, msg, _ in sent:
            c.bus.lcm.publish(channel, msg if isinstance(msg, bytes) else msg.encode())
        c.wait(lambda c: c.status.num_rejected >= len(sent), 20, "every refusal")
        c.wait_time(0.2)
        expected: dict[str, int] = {}
        for channel, _, reason in sent:
            expected[f"{channel}: {reason}"] = expected.get(f"{channel}: {reason}", 0) + 1
        assert _counts(c.status) == expected
        assert c.status.num_rejected == len(sent)
        assert c.status.num_switches == 0 and list(c.state.joint_position) == q0
        # What an operator sees.
        shown = subprocess.run(
            [sys.executable, "-m", "marionette.cli", "dg", "--lcm-url", lcm_url, "status"],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert shown.returncode == 0, shown.stderr
        assert f"refused inputs: {len(sent)}" in shown.stdout
        assert re.search(
            r"CONTROLLER_SPEC\s+6\n\s+5  out of range\n\s+1  invalid spec", shown.stdout
        )
        # One refusal says what and why (the unknown channel, not taken as streamed).
        c.bus.lcm.publish(
            channels.CONTROLLER_SPEC, _spec(8, **{"task.reference_channel": "NOPE"}).encode()
        )
        c.wait(lambda c: "NOPE" in c.status.last_rejection, 20, "the refusal")
        assert "unknown reference_channel 'NOPE'" in c.status.last_rejection


def _key_file(tmp_path) -> str:
    path = tmp_path / "marionette.key"
    path.write_text(secrets.token_hex(32) + "\n")
    path.chmod(0o600)
    return str(path)


def test_signed_commands_pass_and_everything_else_is_refused(
    build_dir, lcm_url, tmp_path, monkeypatch
):
    key_path = _key_file(tmp_path)
    monkeypatch.setenv("MARIONETTE_KEY", key_path)  # the client's bus signs; the controller checks
    with controller_running(build_dir, lcm_url, tmp_path / "logs", *UR10) as c:
        c.send_spec(ControllerSpec(1, "held", [TaskSpec("posture", "posture", 0)]))
        c.wait(lambda c: c.status.active_controller_id == 1, 20, "the signed spec")
        assert c.status.num_rejected == 0  # the spec, its heartbeats: all signed and taken
        key = load_key(key_path)
        now = int(time.time() * 1e6)
        resume = lcmt_command()
        resume.command, resume.source = "resume", "test"  # harmless: already running
        plain = resume.encode()
        intruder = Signer(b"x" * 32)
        signer = Signer(key)
        signed = signer.sign(channels.COMMAND, plain)
        altered = bytearray(signer.sign(channels.COMMAND, plain))
        altered[20] ^= 1  # in the message
        sent = [
            (channels.COMMAND, plain, "unsigned"),
            (channels.COMMAND, signed, None),  # taken
            (channels.COMMAND, signed, "replayed"),
            (channels.SIM_COMMAND, signed, "bad signature"),  # moved to another channel
            (channels.COMMAND, bytes(altered), "bad signature"),
            (channels.COMMAND, intruder.sign(channels.COMMAND, plain), "bad signature"),
            (
                channels.COMMAND,
                Signer(key).sign(channels.COMMAND, plain, now - 60_000_000),
                "stale signature",
            ),
            (channels.CONTROLLER_SPEC, _spec(2).encode(), "unsigned"),
        ]
        with LcmBus(lcm_url, key=False) as raw:
            for channel, data, _ in sent:
                raw.lcm.publish(channel, data)
                time.sleep(0.01)  # in order: the replay after its original
        refused = [s for s in sent if s[2]]
        c.wait(lambda c: c.status.num_rejected >= len(refused), 20, "every refusal")
        c.wait_time(0.2)
        expected: dict[str, int] = {}
        for channel, _, reason in refused:
            expected[f"{channel}: {reason}"] = expected.get(f"{channel}: {reason}", 0) + 1
        assert _counts(c.status) == expected
        assert c.status.mode == "running" and c.status.active_controller_id == 1


def test_a_controller_without_key_refuses_signed_messages(build_dir, lcm_url, tmp_path):
    with controller_running(build_dir, lcm_url, tmp_path / "logs", *UR10) as c:
        msg = lcmt_command()
        msg.command = "hold"
        c.bus.lcm.publish(channels.COMMAND, Signer(b"k" * 32).sign(channels.COMMAND, msg.encode()))
        c.wait(lambda c: c.status.num_rejected == 1, 20, "the refusal")
        assert _counts(c.status) == {"COMMAND: signed, no key": 1}
        assert "--key FILE" in c.status.last_rejection


DRIVER = """
import os, sys, time
import numpy as np
from marionette import channels, lcmt_command, robots
from marionette.control.client import ControllerClient, configuration_from_state
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.streamer import ReferenceStreamer

c = ControllerClient(sys.argv[1])
c.wait_ready(30)
model, _ = robots.load_pinocchio("ur10", with_collision=False)
q0 = configuration_from_state(model, c.state)
c.send_spec(ControllerSpec(10, "driven", [TaskSpec("posture", "posture", 0, gain=10.0,
                                                    streamed=True)], reference_timeout=0.5))
c.wait(lambda c: c.status.active_controller_id == 10, 30)
t = np.arange(20_000) * 1e-3  # 20 s of the shoulder swinging 0.3 rad, streamed 4 s ahead
values = np.tile(q0, (len(t), 1))
values[:, 0] += 0.3 * np.sin(2 * np.pi * t / 4)
derivatives = np.zeros((len(t), model.nv))
derivatives[:, 0] = 0.3 * 2 * np.pi / 4 * np.cos(2 * np.pi * t / 4)
streamer = ReferenceStreamer(c.send_reference, 10, {"posture": (values, derivatives)},
                             c.utime() + 50_000, 1000, 200, 4.0)
if sys.argv[2] == "another machine":  # its heartbeat names a process this machine cannot watch
    c.bus.heartbeat.stop()
    beat = lcmt_command()
    beat.command, beat.source, beat.sender_pid = "heartbeat", "remote supervisor", os.getpid()
    beat.sender_pid_namespace = "another-boot-id/pid:[4026531836]"
print("streaming", flush=True)
while True:
    streamer.pump(c.utime())
    if sys.argv[2] == "another machine":
        beat.utime = c.utime()
        c.bus.publish(channels.COMMAND, beat)
    time.sleep(0.005)
"""


FLOOD = """
import sys, time
import lcm
bus = lcm.LCM(sys.argv[1])
while True:
    bus.publish("DG_REQUEST", b"garbage")
    time.sleep(0.0002)
"""


@pytest.mark.slow
@pytest.mark.parametrize("where", ["same machine", "another machine"])
def test_a_killed_supervisor_makes_it_hold_and_a_new_one_resumes(
    build_dir, lcm_url, tmp_path, where
):
    """On the same machine the controller watches the supervisor's process and holds when it
    exits, long before its timeout (2 s here); a supervisor whose heartbeat names a process of
    another machine is held after exactly its timeout (100 ms)."""
    timeout_s = 2.0 if where == "same machine" else 0.1
    with controller_running(
        build_dir,
        lcm_url,
        tmp_path / "logs",
        *UR10,
        "--state-rate",
        "1000",
        "--supervisor-timeout",
        str(timeout_s),
    ) as c:
        commands = MessageLog(c.bus, channels.ROBOT_COMMAND, lcmt_robot_command)
        journal = MessageLog(c.bus, channels.CONTROLLER_JOURNAL, lcmt_controller_journal)
        driver = subprocess.Popen(
            [sys.executable, "-c", DRIVER, lcm_url, where], stdout=subprocess.PIPE, text=True
        )
        # A flood of garbage on another channel (a message every ~0.3 ms) keeps the controller's
        # LCM thread from ever waiting idle: it must hide neither the exit nor the silence. (A
        # flood long enough to drown the heartbeats holds the robot too: on the safe side.)
        flood = None
        try:
            assert wait_for_line(driver.stdout, "streaming", 60.0) is not None
            c.wait(lambda c: c.status.mode == "running", 20, "the driven controller")
            c.wait_time(1.5)  # moving; the hold controller is armed 1 s after the swap
            flood = subprocess.Popen([sys.executable, "-c", FLOOD, lcm_url])
            c.wait(lambda c: c.status.num_rejected > 50, 10, "the flood")
            driver.send_signal(signal.SIGKILL)
            driver.wait(10)
            c.wait(lambda c: c.status.mode == "holding", 10, "the hold")
        finally:
            driver.kill()
            if flood is not None:
                flood.kill()
                flood.wait(10)
        reason = c.status.mode_reason
        if where == "same machine":
            prefix = f"supervisor exited: its process {driver.pid} ended "
            assert reason.startswith(prefix), reason
            # Within a beat or two of its last message (20 ms apart), far from the 2 s timeout.
            after_ms = float(re.search(r"ended (\d+) ms after", reason).group(1))
            assert after_ms < 500, reason
        else:
            assert reason.startswith("supervisor silent: nothing heard for "), reason
            silent_ms = float(re.search(r"for (\d+) ms", reason).group(1))
            # Never before the timeout; within a few ms of it (a loaded machine adds scheduling).
            assert 100 <= silent_ms <= 130, reason
        assert "controller holds the robot" in reason or "zero-velocity" in reason, reason
        # The robot comes to rest where it was held instead of playing the 4 s it had been sent
        # (the shoulder swings 0.3 rad): the hold controller's blend (50 ms) carries it on a
        # little, its posture task (2/s) brings it back; a zero-velocity hold stops it there.
        c.wait_time(2.0)
        holds = [
            tick
            for j in journal.messages
            for tick, channel in zip(j.tick, j.channel)
            if channel == "CONTROLLER_SILENCE_HOLD"
        ]
        assert len(holds) == 1, holds
        after = [m for m in commands.messages if m.utime >= 1000 * holds[0]]
        q_after = np.array([m.joint_position for m in after])
        assert np.ptp(q_after[:, 0]) < 0.05, np.ptp(q_after[:, 0])
        assert np.abs(after[-1].joint_velocity).max() < 5e-3
        # A new supervisor takes over from the hold.
        c.send_spec(ControllerSpec(11, "resumed", [TaskSpec("posture", "posture", 0)]))
        c.wait(
            lambda c: c.status.active_controller_id == 11 and c.status.mode == "running",
            20,
            "the new supervisor's controller",
        )
        c.wait_time(0.5)
        assert c.status.mode == "running", c.status.mode_reason  # its heartbeat keeps it


# A supervisor whose Python is kept from running: one call that keeps the interpreter's lock for
# argv[2] s (ctypes.PyDLL calls do not release it), then the longest gap between two feeds of its
# heartbeat thread.
STALLED = """
import ctypes, sys, time
from marionette.control.client import ControllerClient
from marionette.control.spec import ControllerSpec, TaskSpec

c = ControllerClient(sys.argv[1])
c.wait_ready(30)
c.send_spec(ControllerSpec(10, "driven", [TaskSpec("posture", "posture", 0)]))
c.wait(lambda c: c.status.active_controller_id == 10, 30)
print("driving", flush=True)
time.sleep(0.5)
ctypes.PyDLL(None).usleep(int(float(sys.argv[2]) * 1e6))
time.sleep(0.1)  # the feeding thread's first feed after the stall measures it
print(f"stalled {c.bus.heartbeat.longest_feed_gap_s:.3f}", flush=True)
time.sleep(60)
"""


def _stalled_supervisor(c, lcm_url: str, stall_s: float) -> tuple[list[str], float]:
    """Runs STALLED for ``stall_s`` next to controller ``c``: the controller's modes seen from
    the stall's start to 1 s after it, and the supervisor's longest feed gap [s]."""
    driver = subprocess.Popen(
        [sys.executable, "-c", STALLED, lcm_url, str(stall_s)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert wait_for_line(driver.stdout, "driving", 60.0) is not None
        c.wait(lambda c: c.status.mode == "running", 20, "the driven controller")
        modes = []
        end = time.monotonic() + 0.5 + stall_s + 1.0
        while time.monotonic() < end:
            modes.append(c.status.mode)
            time.sleep(0.01)
        line = wait_for_line(driver.stdout, "stalled", 10.0)
        assert line is not None
        return modes, float(line.split()[1])
    finally:
        driver.kill()
        driver.wait(10)


@pytest.mark.slow
def test_a_supervisor_kept_from_running_python_stays_heard(build_dir, lcm_url, tmp_path):
    """The heartbeat comes from a C++ thread: a supervisor whose interpreter is held for 0.5 s
    (five times the controller's 100 ms timeout; a heartbeat sent from Python would be silent
    that long) does not make the controller hold."""
    with controller_running(build_dir, lcm_url, tmp_path / "logs", *UR10) as c:
        modes, gap = _stalled_supervisor(c, lcm_url, 0.5)
        assert gap >= 0.45, gap  # the stall happened: Python fed nothing for that long
        assert set(modes) == {"running"}, (set(modes), c.status.mode_reason)


@pytest.mark.slow
def test_a_supervisor_whose_python_hangs_falls_silent(build_dir, lcm_url, tmp_path):
    """...but only while its Python runs within the heartbeat's hang window (1 s): held for
    1.6 s, the beats stop and the controller holds, the silence measured from the last beat."""
    with controller_running(build_dir, lcm_url, tmp_path / "logs", *UR10) as c:
        modes, gap = _stalled_supervisor(c, lcm_url, HEARTBEAT_HANG_S + 0.6)
        assert gap >= HEARTBEAT_HANG_S + 0.5, gap
        assert "holding" in modes, set(modes)
        reason = c.status.mode_reason
        assert reason.startswith("supervisor silent: nothing heard for "), reason


@pytest.mark.slow
def test_a_silence_hold_is_replayed_at_its_tick(build_dir, lcm_url, tmp_path):
    """The hold on a killed supervisor is the loop's decision at a tick that depends on wall-clock
    timing: journaled, a replay takes it at the same tick and reproduces every command."""
    log = tmp_path / "run.lcmlog"
    logger = subprocess.Popen(logger_command(lcm_url, log))
    try:
        time.sleep(0.3)
        with controller_running(build_dir, lcm_url, tmp_path / "logs", *UR10) as c:
            driver = subprocess.Popen(
                [sys.executable, "-c", DRIVER, lcm_url, "same machine"],
                stdout=subprocess.PIPE,
                text=True,
            )
            try:
                assert wait_for_line(driver.stdout, "streaming", 60.0) is not None
                c.wait_time(1.5)
                driver.send_signal(signal.SIGKILL)
                driver.wait(10)
            finally:
                driver.kill()
            c.wait(lambda c: "supervisor exited" in c.status.mode_reason, 10, "the hold")
            # The new supervisor comes once the hold has stopped the swing (the switch-jump
            # limit refuses a spec while the held robot still moves).
            c.wait(lambda c: np.abs(c.state.joint_velocity).max() < 0.02, 10, "the robot at rest")
            c.send_spec(ControllerSpec(11, "resumed", [TaskSpec("posture", "posture", 0)]))
            c.wait(lambda c: c.status.active_controller_id == 11, 20, "the new supervisor")
            c.wait_time(0.5)
        time.sleep(0.5)  # the last journal batch reaches the logger
    finally:
        logger.terminate()
        logger.wait(10)
    journal = [
        ch
        for event in lcm.EventLog(str(log), "r")
        if event.channel == channels.CONTROLLER_JOURNAL
        for ch in lcmt_controller_journal.decode(event.data).channel
    ]
    assert journal.count("CONTROLLER_SILENCE_HOLD") == 1
    result = replay_controller(log)
    assert result["ok"], result["output"]
    assert result["max_difference"] <= 1e-9, result["output"]


def test_the_supervisor_timeout_can_be_switched_off(build_dir, lcm_url, tmp_path):
    with controller_running(
        build_dir, lcm_url, tmp_path / "logs", *UR10, "--supervisor-timeout", "0"
    ) as c:
        with LcmBus(lcm_url) as driver:  # sends one spec, then falls silent
            driver.publish(channels.CONTROLLER_SPEC, _spec(1))
            c.wait(lambda c: c.status.active_controller_id == 1, 20, "the spec")
        c.wait_time(0.5)
        assert c.status.mode == "running", c.status.mode_reason
