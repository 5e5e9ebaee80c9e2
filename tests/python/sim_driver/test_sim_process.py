"""marionette-sim, the MuJoCo scene as a robot driver (cpp/src/sim_driver, docs/driver.md), driven
from Python as marionette-controller --backend driver drives it: every DRIVER_STATE answered by a
DRIVER_COMMAND echoing its sequence and utime."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import lcm
from marionette import (
    REPO_ROOT,
    channels,
    lcmt_camera_image,
    lcmt_driver_command,
    lcmt_driver_state,
    lcmt_driver_status,
    lcmt_object_poses,
    lcmt_sim_command,
)
from marionette.lcm_bus import LcmBus, MessageLog, private_lcm_url
from marionette.lcm_signing import load_key
from marionette.processes import ManagedProcess, ProcessGroup
from marionette.robots import robot

JOINT = "shoulder_pan_joint"  # the UR10's vertical axis: no gravity load on its servo
RAMP_RAD = 0.3
RAMP_S = 0.5

Target = Callable[[float, dict[str, float]], tuple[dict[str, float], dict[str, float]]]


def ramp(t: float, start: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """The start posture with JOINT moved RAMP_RAD over RAMP_S (and held): positions, velocities."""
    q = dict(start)
    q[JOINT] += RAMP_RAD * min(t / RAMP_S, 1.0)
    v = {name: 0.0 for name in start}
    v[JOINT] = RAMP_RAD / RAMP_S if t < RAMP_S else 0.0
    return q, v


class Answerer:
    """Answers each DRIVER_STATE at once (raw LCM: Python's validation would cost more than a
    cycle) with ``target(t, start positions)``; records the states and what it commanded."""

    def __init__(self, url: str, target: Target = ramp) -> None:
        self.lc = lcm.LCM(url)
        self.target = target
        self.answering = True
        self.states: list[Any] = []
        self.commanded: dict[int, dict[str, float]] = {}
        self.start: dict[str, float] | None = None
        self.wrong_joint_at: int | None = None  # sends a command naming a wrong joint first
        self.lc.subscribe(channels.DRIVER_STATE, self._on_state)

    def _on_state(self, _channel: str, data: bytes) -> None:
        s = lcmt_driver_state.decode(data)
        if self.states and s.sequence == self.states[-1].sequence:
            pass  # lockstep: the driver sent it again (our answer was lost or not sent yet)
        else:
            self.states.append(s)
        if not self.answering:
            return
        names = list(s.joint_name)
        if self.start is None:
            self.start = dict(zip(names, s.joint_position, strict=True))
        q, v = self.target(s.utime * 1e-6, self.start)
        self.commanded[s.sequence] = q
        cmd = lcmt_driver_command()
        cmd.utime, cmd.sequence, cmd.protocol_version, cmd.mode = s.utime, s.sequence, 1, 0
        cmd.num_joints = len(names)
        cmd.joint_name = names
        cmd.joint_position = [q[n] for n in names]
        cmd.joint_velocity = [v[n] for n in names]
        cmd.joint_effort = [0.0] * len(names)
        if s.sequence == self.wrong_joint_at:
            cmd.joint_name = ["no_such_joint", *names[1:]]
            self.lc.publish(channels.DRIVER_COMMAND, cmd.encode())
            cmd.joint_name = names
        self.lc.publish(channels.DRIVER_COMMAND, cmd.encode())

    def run(self, until: Callable[[], bool], timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not until():
            assert time.monotonic() < deadline, f"{len(self.states)} states in {timeout_s} s"
            self.lc.handle_timeout(100)


def start_sim(group: ProcessGroup, url: str, *args: str) -> ManagedProcess:
    """marionette-sim on ``url`` (the UR10 unless ``args`` name a robot)."""
    from marionette import BUILD_DIR

    robot = [] if "--robot" in args else ["--robot", "ur10"]
    return group.start("sim", [BUILD_DIR / "marionette-sim", *robot, "--lcm-url", url, *args])


def wait_status(
    log: MessageLog, proc: ManagedProcess, condition: Callable[[Any], bool], timeout_s: float
) -> Any:
    ok = log.wait_for(lambda msgs: bool(msgs) and condition(msgs[-1]), timeout_s)
    last = log.latest()
    assert ok, (
        f"DRIVER_STATUS never satisfied the condition; last: "
        f"{None if last is None else vars_of(last)}\n{proc.log_tail()}"
    )
    return last


def vars_of(msg: Any) -> dict[str, Any]:
    return {name: getattr(msg, name) for name in msg.__slots__}


def stop_cleanly(group: ProcessGroup, proc: ManagedProcess) -> str:
    """Stops the sim (SIGINT) and returns its summary line; it must exit 0."""
    code = group.stop("sim", timeout_s=10.0)
    assert code == 0, f"marionette-sim exited with {code}:\n{proc.log_tail()}"
    summary = [line for line in proc.log_path.read_text().splitlines() if "stopped after" in line]
    assert summary, proc.log_tail()
    return summary[-1]


def test_lockstep_follows_the_commanded_ramp(build_dir: Path, tmp_path: Path) -> None:
    url = private_lcm_url()
    cycles = 1500
    with (
        ProcessGroup(url, tmp_path / "logs") as group,
        LcmBus(url, key=False) as bus,
    ):
        statuses = MessageLog(bus, channels.DRIVER_STATUS, lcmt_driver_status)
        bus.start()
        answerer = Answerer(url)
        answerer.wrong_joint_at = 100
        timing_log = tmp_path / "cycles.csv"
        proc = start_sim(
            group, url, "--speed", "0", "--camera-rate", "0", "--timing-log", str(timing_log)
        )
        answerer.run(lambda: len(answerer.states) >= cycles, timeout_s=120.0)
        group.check_alive()

        # One state per cycle, in order, on the robot's clock.
        sequences = [s.sequence for s in answerer.states]
        assert sequences == list(range(len(sequences)))
        assert all(s.utime == 1000 * s.sequence for s in answerer.states)
        first = answerer.states[0]
        assert first.robot_name == "ur10" and first.protocol_version == 1
        assert not first.has_base
        assert JOINT in first.joint_name

        # The joint follows the ramp (velocity feed-forward) and settles on its end.
        index = list(first.joint_name).index(JOINT)
        lag = [
            abs(s.joint_position[index] - answerer.commanded[s.sequence - 1][JOINT])
            for s in answerer.states[1:]
        ]
        assert max(lag) < 0.02, f"tracking lag up to {max(lag):.4f} rad"
        settled = [
            abs(s.joint_position[index] - answerer.commanded[s.sequence - 1][JOINT])
            for s in answerer.states
            if s.utime >= 1e6 * (RAMP_S + 0.3)
        ]
        assert settled and max(settled) < 3e-3, f"{max(settled) * 1e3:.2f} mrad after settling"
        last = answerer.states[-1]
        assert last.joint_position[index] == pytest.approx(
            answerer.start[JOINT] + RAMP_RAD,  # type: ignore[index]
            abs=3e-3,
        )

        # The command naming a wrong joint was refused, its valid twin taken; lockstep: nothing
        # late, no hold.
        status = wait_status(
            statuses, proc, lambda st: st.sequence >= len(sequences) - 1, timeout_s=5.0
        )
        assert status.commands_refused == 1
        assert "unknown joint 'no_such_joint'" in status.last_refusal
        assert status.commands_taken >= len(sequences) - 1
        assert status.commands_late == 0 and status.holds == 0
        assert not status.holding and status.reason == ""
        summary = stop_cleanly(group, proc)
        assert "refused 1" in summary and "late 0" in summary, summary
    # Every cycle's round trip, none late (the last state may have gone out unanswered).
    lines = timing_log.read_text().splitlines()
    assert lines[0] == "sequence,round_trip_us,late,holding"
    rows = [line.split(",") for line in lines[1:]]
    assert [int(r[0]) for r in rows] == list(range(len(rows))) and len(rows) >= cycles - 1
    assert all(float(r[1]) > 0.0 and r[2:] == ["0", "0"] for r in rows), rows[:5]


def test_paced_driver_holds_without_commands(build_dir: Path, tmp_path: Path) -> None:
    """At --speed 1: holding until commands come, tracking while they come, holding again within
    the watchdog's 10 ms when they stop; SIM_COMMAND moves the scene's free box."""
    url = private_lcm_url()
    scene = REPO_ROOT / "models" / "scenes" / "ur10_box.xml"
    with (
        ProcessGroup(url, tmp_path / "logs") as group,
        LcmBus(url, key=False) as bus,
    ):
        statuses = MessageLog(bus, channels.DRIVER_STATUS, lcmt_driver_status)
        poses = MessageLog(bus, channels.SIM_OBJECT_POSES, lcmt_object_poses)
        bus.start()
        proc = start_sim(group, url, "--speed", "1", "--camera-rate", "0", "--scene", str(scene))
        status = wait_status(statuses, proc, lambda st: st.sequence > 200, timeout_s=30.0)
        assert status.holding and status.reason == "no command yet"
        assert status.commands_taken == 0 and status.holds == 0
        assert status.realtime_factor > 0.5

        # Commands for 0.5 s: tracked.
        answerer = Answerer(url, target=lambda t, start: (start, {n: 0.0 for n in start}))
        answerer.run(lambda: len(answerer.commanded) >= 500, timeout_s=30.0)
        status = wait_status(statuses, proc, lambda st: st.commands_taken >= 400, timeout_s=5.0)
        # Then none: the watchdog holds.
        answerer.answering = False
        status = wait_status(statuses, proc, lambda st: st.holding and st.holds >= 1, timeout_s=5.0)
        assert status.reason.startswith("no command for"), status.reason
        # From the last receipt, on the robot's clock: the timeout less how late that answer came
        # (10 ms when it came in its own cycle; Python on a busy machine is often later).
        assert 0.0 < status.last_hold_reaction_ms <= 10.0, status.last_hold_reaction_ms
        assert status.commands_refused == 0

        # SIM_COMMAND: an unknown object is refused with the known ones; the box moves.
        wait = poses.wait_for(lambda msgs: bool(msgs), 5.0)
        assert wait, proc.log_tail()
        (box,) = poses.latest().objects
        assert box.object_name == "box"
        move = lcmt_sim_command()
        move.command, move.object_name = "set_object_pose", "no_such_box"
        move.quaternion = [1.0, 0.0, 0.0, 0.0]
        bus.publish(channels.SIM_COMMAND, move)
        target = [box.position_world[0] - 0.1, box.position_world[1], box.position_world[2]]
        move.object_name, move.position = "box", target
        bus.publish(channels.SIM_COMMAND, move)

        def moved(msgs: list[Any]) -> bool:
            p = msgs[-1].objects[0].position_world
            return abs(p[0] - target[0]) < 0.01 and abs(p[1] - target[1]) < 0.01

        assert poses.wait_for(moved, 5.0), vars_of(poses.latest().objects[0])
        # The simulated grasp: a known weld is taken (attach, then detach), an unknown one refused.
        for command, weld in [
            ("attach", "grasp/ur10/no_such_gripper/box"),
            ("attach", "grasp/ur10/gripper/box"),
            ("detach", "grasp/ur10/gripper/box"),
        ]:
            move.command, move.object_name = command, weld
            bus.publish(channels.SIM_COMMAND, move)
        time.sleep(0.3)
        summary = stop_cleanly(group, proc)
        log = proc.log_path.read_text()
        assert "'no_such_box' (free objects: box)" in log, log
        assert log.count("SIM_COMMAND refused (") == 2, log
        assert "no weld 'grasp/ur10/no_such_gripper/box' in the scene (welds: " in log, log
        assert "refused 0" in summary and "SIM_COMMAND refused 2" in summary, summary


def _key_file(tmp_path: Path) -> Path:
    path = tmp_path / "marionette.key"
    path.write_text("0123456789abcdef" * 4 + "\n")
    path.chmod(0o600)
    return path


def test_signed_sim_command_only_with_a_key(build_dir: Path, tmp_path: Path) -> None:
    """SIM_COMMAND is a signed channel: with --key, an unsigned request is refused and a signed
    one taken (the box moves); the controller's boundary, in the driver."""
    url = private_lcm_url()
    key_path = _key_file(tmp_path)
    scene = REPO_ROOT / "models" / "scenes" / "ur10_box.xml"
    with (
        ProcessGroup(url, tmp_path / "logs") as group,
        LcmBus(url, key=False) as unsigned,
        LcmBus(url, key=load_key(key_path)) as signed,
    ):
        poses = MessageLog(unsigned, channels.SIM_OBJECT_POSES, lcmt_object_poses)
        unsigned.start()
        proc = start_sim(
            group, url, "--camera-rate", "0", "--scene", str(scene), "--key", str(key_path)
        )
        assert poses.wait_for(lambda msgs: bool(msgs), 30.0), proc.log_tail()
        (box,) = poses.latest().objects
        move = lcmt_sim_command()
        move.command, move.object_name = "set_object_pose", "box"
        move.quaternion = [1.0, 0.0, 0.0, 0.0]
        move.position = [box.position_world[0], box.position_world[1] + 0.1, box.position_world[2]]
        unsigned.publish(channels.SIM_COMMAND, move)
        time.sleep(0.3)
        assert abs(poses.latest().objects[0].position_world[1] - box.position_world[1]) < 0.01
        signed.publish(channels.SIM_COMMAND, move)
        assert poses.wait_for(
            lambda msgs: abs(msgs[-1].objects[0].position_world[1] - move.position[1]) < 0.01, 5.0
        ), vars_of(poses.latest().objects[0])
        stop_cleanly(group, proc)
        log = proc.log_path.read_text()
        assert "SIM_COMMAND refused (unsigned)" in log, log
        assert "signed only" in log


def test_head_camera_frames_on_the_robot_clock(build_dir: Path, tmp_path: Path) -> None:
    """CAMERA_HEAD as the controller's mujoco backend renders it: TIAGo's head camera at 15 Hz of
    robot time; the planar base travels in the state."""
    url = private_lcm_url()
    scene = REPO_ROOT / "models" / "scenes" / "tiago_deburr.xml"
    with (
        ProcessGroup(url, tmp_path / "logs") as group,
        LcmBus(url, key=False) as bus,
    ):
        images = MessageLog(bus, channels.CAMERA_HEAD, lcmt_camera_image)
        states = MessageLog(bus, channels.DRIVER_STATE, lcmt_driver_state)
        bus.start()
        proc = start_sim(
            group,
            url,
            "--robot",
            "tiago",
            "--scene",
            str(scene),
            "--camera-rate",
            "15",
            "--camera-size",
            "160x120",
        )
        assert images.wait_for(lambda msgs: len(msgs) >= 6, 60.0), proc.log_tail()
        stop_cleanly(group, proc)
    frames = images.messages
    utimes = [f.utime for f in frames[1:]]
    # Sampled every 67 cycles (SCHED_IDLE rendering may skip one on a busy machine: the newest
    # snapshot wins, the physics never waits).
    gaps = [b - a for a, b in zip(utimes, utimes[1:], strict=False)]
    assert all(g > 0 and g % 67_000 == 0 for g in gaps), utimes
    image = frames[-1]
    assert (image.width, image.height, image.camera_name) == (160, 120, "head")
    assert image.frame_name == robot("tiago").camera_frame
    assert len(image.rgb) == 160 * 120 * 3 and len(image.depth) == 160 * 120
    assert max(image.rgb) - min(image.rgb) > 50, "a rendered image, not a blank one"
    state = states.latest()
    assert state.robot_name == "tiago" and state.has_base


def run_sim(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    from marionette import BUILD_DIR

    return subprocess.run(
        [str(BUILD_DIR / "marionette-sim"), *args],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )


def test_command_line(build_dir: Path) -> None:
    done = run_sim("--help")
    assert done.returncode == 0 and "--command-timeout" in done.stdout
    done = run_sim("--robot", "ur10", "--speed", "fast")
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "--speed: 'fast'" in done.stderr, done.stderr
    done = run_sim("--speed", "1")
    assert done.returncode == 2 and "--robot NAME|DIR is required" in done.stderr
    done = run_sim("--robot", "no_such_robot", "--lcm-url", private_lcm_url())
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert "no_such_robot" in done.stderr
