"""marionette-controller's safety: continuity check at controller swaps (Agimus §3.2.5.2),
watchdog on streamed references, estop, and garbage on every input channel."""

from __future__ import annotations

import random

import numpy as np
import pinocchio as pin
import pytest

from marionette import (
    channels,
    lcmt_command,
    lcmt_robot_command,
    lcmt_sim_command,
    robots,
)
from marionette.control.client import configuration_from_state, pose_to_vector
from marionette.control.spec import ControllerSpec, TaskSpec, reference_chunk
from marionette.lcm_bus import MessageLog

UR10 = ["--robot", "ur10", "--backend", "kinematic", "--camera-rate", "0"]


def arm_spec(
    controller_id: int,
    posture_reference=None,
    gain: float = 1.0,
    streamed=False,
    timeout: float = 0.05,
) -> ControllerSpec:
    tasks = [TaskSpec("tool", "se3", 0, frame="tool0", gain=gain, streamed=streamed)]
    tasks.append(
        TaskSpec(
            "posture",
            "posture",
            1,
            gain=gain,
            reference=() if posture_reference is None else list(posture_reference),
        )
    )
    return ControllerSpec(
        controller_id,
        f"arm{controller_id}",
        tasks,
        max_switch_velocity_jump=0.05,
        reference_timeout=timeout,
    )


def test_continuous_swap_is_accepted_and_a_discontinuous_one_refused(run_controller, lcm_url):
    with run_controller(*UR10, "--state-rate", "1000") as c:
        commands = MessageLog(c.bus, channels.ROBOT_COMMAND, lcmt_robot_command)
        c.send_spec(arm_spec(1))
        c.wait(
            lambda c: c.status.active_controller_id == 1 and c.status.mode == "running",
            20,
            "controller 1",
        )
        # The same stack again, holding where the robot is: the command stays continuous.
        c.send_spec(arm_spec(2))
        c.wait(lambda c: c.status.active_controller_id == 2, 20, "controller 2")
        c.wait_time(0.2)
        v = np.array([m.joint_velocity for m in commands.messages])
        assert len(v) > 100
        assert np.abs(np.diff(v, axis=0)).max() < 0.05, "the command jumped at the swap"
        # A posture reference 1 rad away at the top level would jump: refused, 2 stays active.
        q = np.array(c.state.joint_position)
        far = q + np.eye(len(q))[0]  # the shoulder 1 rad away
        spec = ControllerSpec(
            3,
            "far",
            [TaskSpec("posture", "posture", 0, gain=5.0, reference=list(far))],
            max_switch_velocity_jump=0.05,
        )
        c.send_spec(spec)
        # The count comes with the tick's snapshot, the decision's text once the LCM thread has
        # collected it: wait for both.
        c.wait(
            lambda c: c.status.num_refused_switches == 1 and "'far'" in c.status.last_switch_result,
            20,
            "the refusal",
        )
        assert "refused controller 'far' (id 3): command jump" in c.status.last_switch_result
        assert c.status.active_controller_id == 2
        assert c.status.mode == "running"
        assert c.status.num_switches == 2


def test_the_swap_check_compares_the_joints_commands_not_a_free_flyers_velocity(run_controller):
    """A free-flyer's velocity drives no motor: a swap that changes only the base's velocity in the
    command is accepted, one that changes a joint's is refused (both would be with the base)."""
    talos = robots.robot("talos")
    model = pin.buildModelFromUrdf(str(talos.urdf), pin.JointModelFreeFlyer())
    root = robots.root_link("talos")
    with run_controller("--robot", "talos", "--backend", "kinematic", "--camera-rate", "0") as c:
        c.wait(lambda c: c.state is not None, 20, "the first state")
        q = configuration_from_state(model, c.state)
        data = model.createData()
        pin.framesForwardKinematics(model, data, q)
        goal = data.oMf[model.getFrameId(root)].copy()
        goal.translation += np.array([0.5, 0.0, 0.0])
        drift = ControllerSpec(  # the base moves toward a goal 0.5 m ahead at 0.5 m/s, joints held
            1,
            "drift",
            [
                TaskSpec("base", "se3", 0, frame=root, gain=1.0, reference=pose_to_vector(goal)),
                TaskSpec("posture", "posture", 1, gain=1.0),
            ],
        )
        c.send_spec(drift)
        c.wait(lambda c: c.status.active_controller_id == 1, 20, "the drifting base")
        hold = ControllerSpec(2, "hold", [TaskSpec("posture", "posture", 0, gain=1.0)])
        c.send_spec(hold)  # base velocity 0.5 -> 0, joints 0 -> 0
        c.wait(lambda c: c.status.active_controller_id == 2, 20, "the swap that stops the base")
        assert c.status.num_refused_switches == 0
        q = configuration_from_state(model, c.state)
        far = q.copy()
        far[model.joints[model.getJointId("arm_right_1_joint")].idx_q] += 1.0
        c.send_spec(
            ControllerSpec(3, "far", [TaskSpec("posture", "posture", 0, gain=1.0, reference=far)])
        )
        c.wait(lambda c: "(id 3)" in c.status.last_switch_result, 20, "the refusal")
        assert "refused controller 'far' (id 3): command jump 1" in c.status.last_switch_result
        assert c.status.active_controller_id == 2


def test_watchdog_holds_when_references_stop_and_estop_latches(run_controller):
    with run_controller(*UR10, "--state-rate", "1000") as c:
        commands = MessageLog(c.bus, channels.ROBOT_COMMAND, lcmt_robot_command)
        c.send_spec(arm_spec(1, streamed=True, timeout=0.05))
        c.wait(lambda c: c.status.active_controller_id == 1, 20, "controller 1")
        model, _ = robots.load_pinocchio("ur10", with_collision=False)
        data = model.createData()
        q = configuration_from_state(model, c.state)
        pin.framesForwardKinematics(model, data, q)
        X = data.oMf[model.getFrameId("tool0")]
        # 300 ms of references moving the tool 1 cm/s upwards, then nothing more.
        t0 = c.utime() + 10_000
        n = 300
        values = np.array(
            [
                pose_to_vector(pin.SE3(X.rotation, X.translation + [0, 0, 0.01 * k / 1000]))
                for k in range(n)
            ]
        )
        derivatives = np.tile([0, 0, 0.01, 0, 0, 0], (n, 1))
        c.send_reference(reference_chunk(1, "tool", t0, values, derivatives))
        last_sample = t0 + 1000 * (n - 1)
        c.wait(lambda c: c.status.mode == "holding", 20, "the watchdog")
        assert "watchdog" in c.status.mode_reason and "tool" in c.status.mode_reason
        c.wait(
            lambda c: any(m.utime > last_sample + 100_000 for m in commands.messages),
            10,
            "more commands",
        )
        moving = [m.utime for m in commands.messages if np.abs(m.joint_velocity).max() > 0.0]
        held = [
            m.utime
            for m in commands.messages
            if m.utime > last_sample and np.abs(m.joint_velocity).max() == 0.0
        ]
        assert moving and held
        first_hold = min(held)
        # Timeout 50 ms after the last sample; the hold starts within 10 ms of that.
        assert last_sample + 50_000 <= first_hold <= last_sample + 60_000, (
            first_hold - last_sample
        ) / 1e3
        assert max(u for u in moving if u < first_hold + 1) < first_hold

        # estop: zero command, latched — a new controller is refused until reset_estop.
        c.send_command("resume")
        c.send_command("estop")
        c.wait(lambda c: c.status.mode == "estopped", 10, "estop")
        c.send_spec(arm_spec(2))
        c.wait(lambda c: c.status.num_refused_switches == 1, 10, "the refused spec")
        assert "estop is latched" in c.status.last_switch_result
        c.send_command("reset_estop")
        c.wait(lambda c: c.status.mode == "holding", 10, "reset")
        c.send_spec(arm_spec(3))
        c.wait(
            lambda c: c.status.active_controller_id == 3 and c.status.mode == "running",
            10,
            "controller 3",
        )


@pytest.mark.slow
def test_a_burst_of_chunks_is_taken_whole_and_a_chunk_after_a_lost_one_refused(run_controller):
    """A supervisor streams 4 s ahead: its first burst is tens of chunks per task at once. LCM
    queues 30 messages per subscription by default and silently drops the rest when the
    controller's LCM thread is late; the next chunk then left a gap, and the stream jumped over it
    (a plank-flip trial jumped 4 s along its plan). The whole burst must be taken, and a chunk
    whose predecessor never came refused with the robot held, never moved ahead. (LCM's drops
    need the LCM thread starved of CPU, as in that trial: on an idle machine the burst alone
    rarely overflows even the default queue; the refusal after a loss is what this test pins
    down.)"""
    with run_controller(*UR10, "--state-rate", "1000") as c:
        spec = ControllerSpec(
            1,
            "streamed",
            [
                TaskSpec("tool", "se3", 0, frame="tool0", streamed=True),
                TaskSpec("wrist", "se3", 1, frame="wrist_1_link", streamed=True),
                TaskSpec("posture", "posture", 2, streamed=True),
            ],
            reference_timeout=0.05,
        )
        c.send_spec(spec)
        c.wait(
            lambda c: c.status.active_controller_id == 1 and c.status.mode == "running",
            20,
            "controller 1",
        )
        model, _ = robots.load_pinocchio("ur10", with_collision=False)
        data = model.createData()
        q = configuration_from_state(model, c.state)
        pin.framesForwardKinematics(model, data, q)
        holds = {
            "tool": pose_to_vector(data.oMf[model.getFrameId("tool0")]),
            "wrist": pose_to_vector(data.oMf[model.getFrameId("wrist_1_link")]),
            "posture": q,
        }
        # 2.4 s in chunks of 40 samples: 60 chunks per task (under a stream's 64-chunk queue),
        # 180 messages at once.
        per_chunk, chunks = 40, 60
        t0 = c.utime() + 200_000
        for k in range(chunks):
            for task, hold in holds.items():
                c.send_reference(
                    reference_chunk(
                        1,
                        task,
                        t0 + 1000 * per_chunk * k,
                        np.tile(hold, (per_chunk, 1)),
                        sequence=k,
                    )
                )
        end = t0 + 1000 * per_chunk * chunks  # one past the last sample sent
        # Chunk 60 (1 s) lost, then chunk 61: played, it would keep the robot going until end + 2 s.
        c.send_reference(
            reference_chunk(
                1, "tool", end + 1_000_000, np.tile(holds["tool"], (1000, 1)), sequence=chunks + 1
            )
        )
        c.wait(lambda c: c.status.utime > end - 200_000, 20, "the end of the burst")
        assert c.status.mode == "running", f"a chunk of the burst was lost: {c.status.mode_reason}"
        assert c.status.num_rejected == 1, list(
            zip(c.status.rejection_reason, c.status.rejection_count)
        )
        assert "chunk 61 of a reference whose chunk 60 never came" in c.status.last_rejection, (
            c.status.last_rejection
        )
        # The refused chunk is not played: the stream runs dry at its end and the watchdog holds.
        c.wait(lambda c: c.status.mode == "holding", 10, "the watchdog")
        assert "watchdog" in c.status.mode_reason, c.status.mode_reason
        assert c.status.utime < end + 500_000, "the watchdog did not fire at the end of the burst"


def _garbage(rng: random.Random, valid: bytes, channel: str, kind: int) -> bytes:
    """A message that must be refused: random bytes, a truncated or extended valid message,
    or a valid message with its fingerprint flipped."""
    if kind == 0:
        return bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 200)))
    if kind == 1:
        return valid[: rng.randrange(0, len(valid))]
    if kind == 2:
        return valid + bytes(rng.getrandbits(8) for _ in range(rng.randrange(1, 20)))
    corrupted = bytearray(valid)
    corrupted[rng.randrange(0, 8)] ^= 1 << rng.randrange(8)
    return bytes(corrupted)


def _semantic_garbage(rng: random.Random, channel: str, k: int, utime: int):
    """Well-formed messages on ``channel`` with content the controller must refuse."""
    if channel == channels.CONTROLLER_SPEC:
        # Built valid, then broken the ways a buggy sender would (the Python side refuses most).
        msg = ControllerSpec(
            1000 + k, "bad", [TaskSpec("t", "se3", 0, frame="left_sole_link")]
        ).to_lcm()
        task = msg.tasks[0]
        breakage = rng.randrange(6)
        if breakage == 0:
            task.frame = "no_such_frame"
        elif breakage == 1:
            task.kind = "teleport"
        elif breakage == 2:
            task.kind, task.joint_name, task.num_joints = "posture", ["no_such_joint"], 1
        elif breakage == 3:
            task.reference, task.num_reference = [0, 0, 0, 2.0, 0, 0, 0], 7
        elif breakage == 4:
            task.kind, task.reference, task.num_reference = "position", [float("nan")] * 3, 3
        else:
            msg.max_switch_velocity_jump = float("nan")
        return msg
    if channel == channels.TASK_REFERENCE:
        values = np.zeros((3, 7))
        values[:, 3] = 1.0
        if rng.random() < 0.5:
            values[1, 0] = float("nan")
        return reference_chunk(
            rng.choice([999999, 1]),
            rng.choice(["tool", "nothing"]),
            utime,
            values if rng.random() < 0.5 else np.zeros((2, 3)),
        )
    if channel == channels.COMMAND:
        msg = lcmt_command()
        msg.command = rng.choice(["jump", "", "HALT!", "resume please"])
        return msg
    msg = lcmt_sim_command()
    msg.command = rng.choice(["set_object_pose", "explode"])
    msg.object_name = "no_such_object"
    msg.quaternion = [1.0, 0, 0, 0]
    return msg


@pytest.mark.slow
def test_garbage_on_every_input_channel_is_counted_and_never_moves_the_robot(run_controller):
    rng = random.Random(20261121)
    with run_controller(
        "--robot",
        "talos",
        "--scene",
        str(robots.robot("talos").mjcf),
        "--speed",
        "1",
        "--camera-rate",
        "0",
        "--status-rate",
        "200",
    ) as c:
        valid = {
            channels.CONTROLLER_SPEC: ControllerSpec(1, "ok", [TaskSpec("posture", "posture", 0)])
            .to_lcm()
            .encode(),
            channels.TASK_REFERENCE: reference_chunk(1, "posture", 0, np.zeros((1, 3))).encode(),
            channels.COMMAND: lcmt_command().encode(),
            channels.SIM_COMMAND: lcmt_sim_command().encode(),
        }
        base0 = c.base_position()
        sent = 0
        per_channel = 10_000
        for k in range(4 * per_channel):
            channel = list(valid)[k % 4]
            if k % 10 < 2:
                c.bus.publish(channel, _semantic_garbage(rng, channel, k, c.utime()))
            else:
                c.bus.lcm.publish(channel, _garbage(rng, valid[channel], channel, rng.randrange(4)))
            sent += 1
            if sent % 50 == 0:  # closed loop: never outrun the receiving side
                c.wait(lambda c, n=sent: c.status.num_rejected >= n, 30, f"{sent} rejections")
        c.wait(lambda c: c.status.num_rejected >= sent, 30, "every rejection")
        c.wait_time(0.5)
        assert c.status.num_rejected == sent, "every message is counted once as rejected"
        reasons = dict(zip(c.status.rejection_reason, c.status.rejection_count))
        assert sum(reasons.values()) == sent
        for channel in valid:
            assert sum(n for r, n in reasons.items() if r.startswith(channel)) >= per_channel, (
                channel
            )
        assert c.status.mode == "holding" and c.status.num_switches == 0
        assert np.linalg.norm(c.base_position() - base0) < 0.005, "the robot moved"
        assert c.process.alive()
