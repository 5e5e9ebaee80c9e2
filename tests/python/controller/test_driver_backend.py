"""marionette-controller --backend driver against a robot's driver written here: a perfect
position-servoed UR10 (the measured position is the last commanded one) that publishes a state and
waits for the controller's answer, in lockstep, on a private LCM URL.

Checked: the controller starts from the robot's first state and its first command is that state;
each command echoes its state's sequence and time; a spec moves the robot; every malformed or
misordered state (NaN, lying sizes, missing or unknown joints, a duplicate, an older sequence, a
clock that goes back or jumps) is refused, counted under its reason, never answered, and holds
the robot with the reason in CONTROLLER_STATUS — and the next good state is answered; a silent
driver holds the robot ("driver silent"); a driven run recorded with marionette-logger replays
exactly."""

from __future__ import annotations

import json
import math
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import lcm
import marionette
from marionette import channels, lcmt_driver_command, lcmt_driver_state, robots
from marionette.control.client import ControllerClient
from marionette.control.replay_cli import JOURNAL_NAME, replay_controller
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.lcm_bus import logger_command
from marionette.processes import ProcessGroup

ROBOT = "ur10"


def _layout() -> tuple[list[str], list[str]]:
    """The UR10's joints as the controller reads them (every 1-dof joint of its Pinocchio
    model, in order) and its measured bodies (contact then grip bodies, as the controller's
    --describe-robot says)."""
    model, _ = robots.load_pinocchio(ROBOT, with_collision=False)
    joints = [
        model.names[j]
        for j in range(1, model.njoints)
        if model.joints[j].nq == 1 and model.joints[j].nv == 1
    ]
    described = subprocess.run(
        [marionette.BUILD_DIR / "marionette-controller", "--robot", ROBOT, "--describe-robot"],
        capture_output=True,
        text=True,
        check=True,
    )
    robot = json.loads(described.stdout)
    return joints, [*robot["contact_bodies"], *robot["grip_bodies"]]


class LockstepRobot:
    """A driver: publishes DRIVER_STATE k (robot clock 1 ms per cycle), waits up to
    ``answer_timeout_s`` for the DRIVER_COMMAND answering k, takes its positions as the next
    measurement. ``inject(make)`` publishes ``make(next_state)`` once, between two cycles, outside
    the sequence (a malformed or misordered message)."""

    def __init__(self, url: str, q0: list[float], answer_timeout_s: float = 0.2) -> None:
        self.joints, self.bodies = _layout()
        self.q = list(q0)
        self.lc = lcm.LCM(url)
        self.answers: dict[int, lcmt_driver_command] = {}
        self.sequence = 0
        self.answer_timeout_s = answer_timeout_s
        self.paused = threading.Event()
        self._injections: list[Callable[[lcmt_driver_state], bytes]] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.lc.subscribe(channels.DRIVER_COMMAND, self._on_command)
        self._thread = threading.Thread(target=self._run, daemon=True)

    def state(self, sequence: int) -> lcmt_driver_state:
        n = len(self.joints)
        s = lcmt_driver_state()
        s.utime, s.sequence, s.protocol_version, s.robot_name = 1000 * sequence, sequence, 1, ROBOT
        s.num_joints, s.joint_name = n, list(self.joints)
        s.joint_position, s.joint_velocity, s.joint_effort = list(self.q), [0.0] * n, [0.0] * n
        s.has_base, s.base_quaternion = False, [1.0, 0.0, 0.0, 0.0]
        s.num_wrenches, s.wrench_body = len(self.bodies), list(self.bodies)
        s.wrench = [[0.0] * 6 for _ in self.bodies]
        return s

    def _on_command(self, _channel: str, data: bytes) -> None:
        msg = lcmt_driver_command.decode(data)
        with self._lock:
            self.answers[msg.sequence] = msg

    def inject(self, make: Callable[[lcmt_driver_state], bytes]) -> None:
        with self._lock:
            self._injections.append(make)

    def _run(self) -> None:
        while not self._stop.is_set():
            if self.paused.is_set():
                self.lc.handle_timeout(5)
                continue
            with self._lock:
                injections, self._injections = self._injections, []
            for make in injections:
                self.lc.publish(channels.DRIVER_STATE, make(self.state(self.sequence)))
            k = self.sequence
            self.lc.publish(channels.DRIVER_STATE, self.state(k).encode())
            deadline = time.monotonic() + self.answer_timeout_s
            while k not in self.answers and time.monotonic() < deadline:
                self.lc.handle_timeout(5)
            with self._lock:
                answer = self.answers.get(k)
            if answer is not None:
                order = {name: i for i, name in enumerate(answer.joint_name)}
                self.q = [answer.joint_position[order[j]] for j in self.joints]
            self.sequence = k + 1

    def __enter__(self) -> LockstepRobot:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)


def _wait(condition: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def _q0() -> list[float]:
    joints, _ = _layout()
    return [0.1 * (i + 1) if j != "finger_joint" else 0.0 for i, j in enumerate(joints)]


def _start(group: ProcessGroup, build_dir: Path, url: str, *extra: str):
    return group.start(
        "controller",
        [
            build_dir / "marionette-controller",
            "--lcm-url",
            url,
            "--robot",
            ROBOT,
            "--backend",
            "driver",
            "--status-rate",
            "50",
            "--supervisor-timeout",
            "0",
            *extra,
        ],
    )


def _posture_spec(target: list[float], controller_id: int = 1) -> ControllerSpec:
    """A posture task to ``target``; the swap may jump (the robot is a perfect servo)."""
    task = TaskSpec("posture", "posture", 0, gain=5.0, reference=target)
    return ControllerSpec(controller_id, "posture", [task], max_switch_velocity_jump=100.0)


def test_the_controller_drives_a_robot_through_its_driver(build_dir, lcm_url, tmp_path):
    q0 = _q0()
    with (
        ProcessGroup(lcm_url, tmp_path / "logs") as group,
        ControllerClient(lcm_url) as client,
        LockstepRobot(lcm_url, q0) as robot,
    ):
        _start(group, build_dir, lcm_url, "--driver-timeout", "0.5")
        client.wait_ready(30.0, processes=group)
        _wait(lambda: len(robot.answers) > 10, 10.0, "the controller's answers")
        first = robot.answers[min(robot.answers)]
        assert first.joint_position == pytest.approx(q0, abs=0.0), "the first command jumped"
        for k, answer in list(robot.answers.items()):
            assert answer.sequence == k and answer.utime == 1000 * k
        target = [0.0, -1.0, 1.2, -0.2, 1.0, 0.3, 0.0]
        client.send_spec(_posture_spec(target))
        client.wait(lambda c: c.status.active_controller_id == 1, 10.0, "the posture spec")
        _wait(
            lambda: max(abs(a - b) for a, b in zip(robot.q, target, strict=True)) < 1e-3,
            60.0,
            "the robot at the posture",
        )
        assert client.status.mode == "running", client.status.mode_reason


def _refusals(client: ControllerClient) -> dict[str, int]:
    s = client.status
    return dict(zip(s.rejection_reason, s.rejection_count, strict=True))


def _nan(s: lcmt_driver_state) -> bytes:
    s.joint_position[0] = math.nan
    return s.encode()


def _lying_size(s: lcmt_driver_state) -> bytes:
    data = bytearray(s.encode())
    at = data.find(ROBOT.encode() + b"\0") + len(ROBOT) + 1  # num_joints follows robot_name
    data[at : at + 4] = (2**30).to_bytes(4, "big")
    return bytes(data)


def _missing_joint(s: lcmt_driver_state) -> bytes:
    s.num_joints -= 1
    for field in ("joint_name", "joint_position", "joint_velocity", "joint_effort"):
        getattr(s, field).pop()
    return s.encode()


def _unknown_joint(s: lcmt_driver_state) -> bytes:
    s.joint_name[0] = "no_such_joint"
    return s.encode()


def _older(s: lcmt_driver_state) -> bytes:
    s.sequence -= 5
    s.utime -= 5000
    return s.encode()


def _duplicate(s: lcmt_driver_state) -> bytes:  # the state the controller took last
    s.sequence -= 1
    s.utime -= 1000
    return s.encode()


def _clock_back(s: lcmt_driver_state) -> bytes:
    s.utime -= 10_000
    return s.encode()


BAD_STATES = [
    (_nan, "out of range"),
    (_lying_size, "over maximum"),
    (_missing_joint, "does not fit the robot"),
    (_unknown_joint, "does not fit the robot"),
    (_older, "out of order"),
    (_duplicate, "duplicated"),
    (_clock_back, "clock went back"),
]


def test_bad_states_are_refused_counted_never_answered_and_hold_the_robot(
    build_dir, lcm_url, tmp_path
):
    with (
        ProcessGroup(lcm_url, tmp_path / "logs") as group,
        ControllerClient(lcm_url) as client,
        LockstepRobot(lcm_url, _q0()) as robot,
    ):
        _start(group, build_dir, lcm_url, "--driver-timeout", "0.5")
        client.wait_ready(30.0, processes=group)
        target = list(robot.q)
        for i, (make, category) in enumerate(BAD_STATES):
            client.send_spec(_posture_spec(target, i + 1))
            client.wait(lambda c, i=i: c.status.active_controller_id == i + 1, 10.0, "a spec")
            client.wait(lambda c: c.status.mode == "running", 5.0, "running")
            before = _refusals(client).get(f"DRIVER_STATE: {category}", 0)
            answered = set(robot.answers)
            robot.inject(make)
            client.wait(
                lambda c, b=before, cat=category: _refusals(c).get(f"DRIVER_STATE: {cat}", 0) > b,
                10.0,
                f"the refusal '{category}'",
            )
            client.wait(lambda c: c.status.mode == "holding", 5.0, "the hold")
            assert "refused" in client.status.mode_reason, client.status.mode_reason
            # The refused message was never answered: every answer since is a good state's.
            n = robot.sequence
            _wait(lambda n=n: robot.sequence > n + 3, 10.0, "good states after the bad one")
            new = set(robot.answers) - answered
            assert new and all(robot.answers[k].utime == 1000 * k for k in new)
        # A jump of the robot's clock: refused, held, and the clock goes on from there.
        before = _refusals(client).get("DRIVER_STATE: clock jump", 0)
        robot.paused.set()
        time.sleep(0.05)
        jump = robot.state(robot.sequence)
        jump.utime += 1_000_000
        robot.lc.publish(channels.DRIVER_STATE, jump.encode())
        client.wait(
            lambda c: _refusals(c).get("DRIVER_STATE: clock jump", 0) > before, 10.0, "clock jump"
        )


def test_a_silent_driver_holds_the_robot(build_dir, lcm_url, tmp_path):
    with (
        ProcessGroup(lcm_url, tmp_path / "logs") as group,
        ControllerClient(lcm_url) as client,
        LockstepRobot(lcm_url, _q0()) as robot,
    ):
        _start(group, build_dir, lcm_url, "--driver-timeout", "0.05")
        client.wait_ready(30.0, processes=group)
        client.send_spec(_posture_spec(list(robot.q)))
        client.wait(lambda c: c.status.mode == "running", 10.0, "running")
        robot.paused.set()
        client.wait(lambda c: c.status.mode == "holding", 5.0, "the hold")
        assert client.status.mode_reason.startswith("driver silent"), client.status.mode_reason
        robot.paused.clear()  # states again: answered, the robot still holds until resumed
        n = len(robot.answers)
        _wait(lambda: len(robot.answers) > n + 10, 10.0, "answers after the silence")
        assert client.status.mode == "holding"


def test_a_driven_run_replays_exactly(build_dir, lcm_url, tmp_path):
    log = tmp_path / "run.lcmlog"
    logger = subprocess.Popen(
        logger_command(lcm_url, log),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        time.sleep(0.3)
        with (
            ProcessGroup(lcm_url, tmp_path / "logs") as group,
            ControllerClient(lcm_url) as client,
            LockstepRobot(lcm_url, _q0()) as robot,
        ):
            # The controller's own journal beside the log, as a demo's: a network logger misses
            # what the kernel drops on a loaded machine.
            journal = str(tmp_path / JOURNAL_NAME)
            _start(
                group,
                build_dir,
                lcm_url,
                *("--driver-timeout", "0.5", "--state-rate", "1000", "--journal", journal),
            )
            client.wait_ready(30.0, processes=group)
            client.send_spec(_posture_spec([0.2, -0.8, 1.0, 0.1, 0.9, -0.2, 0.0]))
            client.wait(lambda c: c.status.active_controller_id == 1, 10.0, "the spec")
            n = robot.sequence
            _wait(lambda: robot.sequence > n + 1500, 60.0, "1.5 s of driven control")
            group.stop("controller", timeout_s=10.0)
        time.sleep(0.5)
    finally:
        logger.terminate()
        logger.wait(10)
    result = replay_controller(log)
    assert result["ok"], result
    # ROBOT_COMMAND is sampled on the wall clock (--state-rate): not every tick's is in the log.
    assert result["ticks"] > 1500 and result["commands_compared"] > 100, result
    assert np.isclose(result["max_difference"], 0.0, atol=1e-9), result
