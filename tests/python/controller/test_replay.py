"""Deterministic replay: a 30 s TALOS run in MuJoCo driven over LCM (a controller spec,
streamed gripper references, hold/resume, a gain set through introspection, an object moved in
the simulator) is recorded with marionette-logger; `marionette replay LOG --controller` re-runs the
graph offline from the journal and must reproduce every recorded command to 1e-9. A log whose
inputs or commands were tampered with must be caught, with the first diverging tick named."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import lcm
from marionette import lcmt_robot_command, robots
from marionette.control.client import configuration_from_state, pose_to_vector
from marionette.control.introspection import GraphClient
from marionette.control.replay_cli import replay_controller
from marionette.control.spec import ControllerSpec, TaskSpec, reference_chunk
from marionette.lcm_bus import logger_command
from tests_support import controller_running

SCENE = str(robots.MODELS_DIR / "scenes" / "talos_plank.xml")


def _record(build_dir: Path, lcm_url: str, log: Path) -> None:
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    data = model.createData()
    logger = subprocess.Popen(
        logger_command(lcm_url, log),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        time.sleep(0.3)  # subscribed before the controller's first message
        with controller_running(
            build_dir,
            lcm_url,
            log.parent / "logs",
            "--robot",
            "talos",
            "--scene",
            SCENE,
            "--speed",
            "0",
            "--camera-rate",
            "0",
        ) as c:
            tasks = [
                TaskSpec("left_foot", "se3", 0, frame="left_sole_link", gain=10.0),
                TaskSpec("right_foot", "se3", 0, frame="right_sole_link", gain=10.0),
                TaskSpec("com", "com", 0, gain=10.0),
                TaskSpec(
                    "right_gripper",
                    "se3",
                    1,
                    frame="gripper_right_base_link",
                    gain=5.0,
                    streamed=True,
                ),
                TaskSpec("posture", "posture", 2, gain=1.0),
            ]
            c.send_spec(ControllerSpec(1, "reach", tasks, max_switch_velocity_jump=0.05))
            c.wait(lambda c: c.status.active_controller_id == 1, 30.0, "the controller")
            q = configuration_from_state(model, c.state)
            pin.framesForwardKinematics(model, data, q)
            start = pin.SE3(data.oMf[model.getFrameId("gripper_right_base_link")])
            s = np.linspace(0.0, 1.0, 500)
            values = [
                pose_to_vector(pin.SE3(start.rotation, start.translation + [0.04 * b, 0, 0.04 * b]))
                for b in s
            ]
            t0 = c.utime() + 20_000
            c.send_reference(reference_chunk(1, "right_gripper", t0, values[:250]))
            c.send_reference(
                reference_chunk(1, "right_gripper", t0 + 250_000, values[250:], last=True)
            )
            c.wait_time(0.6)
            c.send_command("hold")
            c.wait_time(0.2)
            c.send_command("resume")
            with GraphClient(lcm_url) as dg:
                dg.set("c1_posture.gain", 2.5)
            plank = c.object_pose("plank")
            c.move_object("plank", pin.SE3(plank.rotation, plank.translation + [0.0, 0.02, 0.0]))
            c.wait_time(0.8)
            # Standing with the final stack up to 30 s of controller time (the run length).
            c.wait_time(30.0 - c.utime() * 1e-6, timeout_s=120.0)
        time.sleep(0.5)  # the controller's last journal batch reaches the logger
    finally:
        logger.terminate()
        logger.wait(10)


@pytest.fixture(scope="module")
def run_log(tmp_path_factory, build_dir, lcm_url) -> Path:
    log = tmp_path_factory.mktemp("replay") / "run.lcmlog"
    _record(build_dir, lcm_url, log)
    return log


@pytest.mark.slow
def test_replay_reproduces_every_recorded_command(run_log):
    result = replay_controller(run_log)
    assert result["problems"] == [], result["output"]
    assert result["journal_mismatches"] == 0, result["output"]
    # spec + 2 chunks + hold + resume + set + move, consumed by the loop at recorded ticks
    assert result["inputs"] >= 7, result["output"]
    # ROBOT_COMMAND goes out at 100 Hz of wall time; unpaced, that is a few hundred over the run
    assert result["commands_compared"] > 300, result["output"]
    assert result["ticks"] >= 29_900, result["output"]  # the whole 30 s
    assert result["max_difference"] <= 1e-9, result["output"]
    assert result["ok"], result["output"]
    print(result["output"])
    # and the motion replayed was not trivial: the arm moved
    commands = _commands(run_log)
    positions = np.array([c.joint_position for c in commands])
    assert np.ptp(positions, axis=0).max() > 0.05


def _commands(log: Path) -> list:
    out = []
    for event in lcm.EventLog(str(log), "r"):
        if event.channel == "ROBOT_COMMAND":
            out.append(lcmt_robot_command.decode(event.data))
    return out


def _rewrite(src: Path, dst: Path, edit) -> None:
    """Copies an LCM log, passing each event through ``edit(channel, data) -> data | None``."""
    out = lcm.EventLog(str(dst), "w", overwrite=True)
    for event in lcm.EventLog(str(src), "r"):
        data = edit(event.channel, event.data)
        if data is not None:
            out.write_event(event.timestamp, event.channel, data)
    out.close()


@pytest.mark.slow
def test_a_tampered_command_is_reported_at_its_tick(run_log, tmp_path):
    commands = _commands(run_log)
    victim = commands[len(commands) // 2]

    def edit(channel, data):
        if channel != "ROBOT_COMMAND":
            return data
        msg = lcmt_robot_command.decode(data)
        if msg.tick == victim.tick:
            msg.joint_position = list(msg.joint_position)
            msg.joint_position[3] += 1e-6
        return msg.encode()

    tampered = tmp_path / "tampered.lcmlog"
    _rewrite(run_log, tampered, edit)
    result = replay_controller(tampered)
    assert not result["ok"]
    assert result["first_divergence_tick"] == victim.tick
    assert f"joint_position[{victim.joint_name[3]}]" in result["first_divergence"]
    assert 0.9e-6 < result["max_difference"] < 1.1e-6


@pytest.mark.slow
def test_a_missing_input_is_named(run_log, tmp_path):
    dropped = []

    def edit(channel, data):
        if channel == "TASK_REFERENCE" and not dropped:
            dropped.append(data)
            return None
        return data

    lossy = tmp_path / "lossy.lcmlog"
    _rewrite(run_log, lossy, edit)
    result = replay_controller(lossy)
    assert not result["ok"]
    assert any("TASK_REFERENCE message consumed at tick" in p for p in result["problems"]), result[
        "problems"
    ]
    assert result["first_divergence_tick"] >= 0  # without that chunk the arm does not move the same


def test_a_log_without_journal_is_a_clear_error(tmp_path):
    empty = tmp_path / "empty.lcmlog"
    lcm.EventLog(str(empty), "w", overwrite=True).close()
    with pytest.raises(RuntimeError, match="holds no CONTROLLER_JOURNAL"):
        replay_controller(empty)
    with pytest.raises(FileNotFoundError):
        replay_controller(tmp_path / "absent.lcmlog")
