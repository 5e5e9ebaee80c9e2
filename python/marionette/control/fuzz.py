"""Fuzzing a running marionette-controller on its six input channels with structure-aware
mutations (:mod:`marionette.lcm_fuzz`), each one predicted refused — and why — by the Python
validator walking the same schema as the controller's: the controller must count every message
under its channel and that very reason (CONTROLLER_STATUS), and stay alive and still.

    report = fuzz_controller(client, 100_000, random.Random(0))
    report.expected == report.counted        # (channel, reason) -> messages

Used by tests/python/fuzz (10^5 messages, in `make test` and `make sanitize`) and bench/lcm_soak.
"""

from __future__ import annotations

import random
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from marionette import (
    channels,
    lcmt_command,
    lcmt_controller_spec,
    lcmt_controller_status,
    lcmt_dg_request,
    lcmt_footstep,
    lcmt_footstep_plan,
    lcmt_robot_state,
    lcmt_sim_command,
    lcmt_task_reference,
)
from marionette.control.introspection import rejections_by_channel
from marionette.control.spec import ControllerSpec, TaskSpec, reference_chunk
from marionette.lcm_fuzz import Fuzzer
from marionette.lcm_signing import SIGNED_NO_KEY, has_trailer
from marionette.lcm_validate import TRAILING_BYTES, LcmType, validate

# What marionette-controller subscribes to, and the type of each.
INPUTS = {
    channels.CONTROLLER_SPEC: lcmt_controller_spec,
    channels.TASK_REFERENCE: lcmt_task_reference,
    channels.COMMAND: lcmt_command,
    channels.SIM_COMMAND: lcmt_sim_command,
    channels.DG_REQUEST: lcmt_dg_request,
    channels.FOOTSTEP_PLAN: lcmt_footstep_plan,
}


def valid_inputs(now_us: int) -> dict[str, bytes]:
    """One valid message per input channel, every array and string of it non-empty (so that each
    can lie), the reference stamped at ``now_us`` (controller time)."""
    spec = ControllerSpec(
        900_000,
        "fuzz",
        [
            TaskSpec("tool", "se3", 0, frame="tool0", reference=[0.5, 0, 0.4, 1, 0, 0, 0]),
            TaskSpec("posture", "posture", 1, joints=["shoulder_pan_joint"], mask=[True] * 3),
        ],
    ).to_lcm(now_us)
    spec.tasks[1].parameter_name, spec.tasks[1].parameter_value = ["force_target"], [5.0]
    spec.tasks[1].num_parameters = 1
    reference = reference_chunk(
        900_000,
        "tool",
        now_us,
        np.tile([0.5, 0.0, 0.4, 1.0, 0.0, 0.0, 0.0], (3, 1)),
        np.full((3, 6), 0.01),
        sequence=1,
    )
    command = lcmt_command()
    command.utime, command.command, command.source, command.reason = now_us, "hold", "fuzz", "x"
    sim = lcmt_sim_command()
    sim.utime, sim.command, sim.object_name = now_us, "set_object_pose", "box"
    sim.position, sim.quaternion = [0.1, 0.2, 0.3], [1.0, 0.0, 0.0, 0.0]
    request = lcmt_dg_request()
    request.utime, request.request_id, request.client, request.command = 1, 7, "fuzz", "get"
    request.signal, request.num_signals = ["robot.configuration", "safety.command"], 2
    request.value, request.num_values, request.rate = [1.0, 2.0, 3.0], 3, 10.0
    plan = lcmt_footstep_plan()
    plan.utime, plan.plan_id, plan.first_step_index = 1, 3, 0
    for k in range(2):
        s = lcmt_footstep()
        s.index, s.is_left, s.x, s.y, s.yaw = k, k == 0, 0.2 * k, 0.1, 0.0
        s.duration, s.double_support, s.step_height = 0.8, 0.1, 0.05
        s.via, s.num_via = [[0.1, 0.1, 0.05]], 1
        plan.steps.append(s)
    plan.num_steps, plan.stop_at_end = 2, True
    messages = {
        channels.CONTROLLER_SPEC: spec,
        channels.TASK_REFERENCE: reference,
        channels.COMMAND: command,
        channels.SIM_COMMAND: sim,
        channels.DG_REQUEST: request,
        channels.FOOTSTEP_PLAN: plan,
    }
    out = {}
    for channel, msg in messages.items():
        data = msg.encode()
        refusal = validate(INPUTS[channel], data, now_us)
        if refusal is not None:  # the bases themselves must pass
            raise AssertionError(f"{channel}: the base message is refused: {refusal}")
        out[channel] = data
    return out


def _foreign_types() -> list[bytes]:
    """Valid messages of the controller's output types (type confusion across channels)."""
    state, status = lcmt_robot_state(), lcmt_controller_status()
    state.robot_name, status.mode = "some_robot", "running"
    return [state.encode(), status.encode()]


def predict(lcm_type: LcmType, data: bytes, now_us: int) -> str | None:
    """The reason the controller (without a key) refuses ``data`` at its boundary, None if it
    passes there."""
    refusal = validate(lcm_type, data, now_us)
    if refusal is None:
        return None
    if refusal.reason == TRAILING_BYTES and has_trailer(data):
        return SIGNED_NO_KEY
    return refusal.reason


@dataclass
class FuzzReport:
    sent: Counter = field(default_factory=Counter)  # channel -> messages
    expected: Counter = field(default_factory=Counter)  # (channel, reason) -> messages
    counted: Counter = field(default_factory=Counter)  # the same, from CONTROLLER_STATUS
    kinds: Counter = field(default_factory=Counter)  # mutation kind -> messages
    skipped: int = 0  # mutations that stayed valid (not sent)
    seconds: float = 0.0

    def per_channel(self) -> dict[str, tuple[int, int]]:
        """channel -> (sent, counted as refused)."""
        return {
            ch: (self.sent[ch], sum(n for (c, _), n in self.counted.items() if c == ch))
            for ch in INPUTS
        }


def _counters(status) -> Counter:
    return Counter(
        {
            (channel, reason): n
            for channel, reasons in rejections_by_channel(status).items()
            for reason, n in reasons.items()
        }
    )


def fuzz_controller(
    client,
    messages: int,
    rng: random.Random,
    batch: int = 120,
    timeout_s: float = 30.0,
    progress: Callable[[FuzzReport], None] | None = None,
) -> FuzzReport:
    """Sends ``messages`` mutated messages round-robin over the input channels through
    ``client`` (a ControllerClient), ``batch`` at a time, each batch waited for until the
    controller counted it (LCM queues 30 messages per subscription: a burst is not a test of
    UDP). Returns what was sent, predicted and counted."""
    report = FuzzReport()
    fuzzer = Fuzzer(rng)
    foreign = _foreign_types()
    order = list(INPUTS)
    client.wait(lambda c: c.status is not None, 10.0, "a status")
    baseline = _counters(client.status)
    total0 = client.status.num_rejected
    start = time.monotonic()
    k = 0
    while k < messages:
        now_us = client.utime()
        bases = valid_inputs(now_us)
        others = [*bases.values(), *foreign]
        n = min(batch, messages - k)
        sent = 0
        for i in range(n):
            channel = order[(k + i) % len(order)]
            lcm_type = INPUTS[channel]
            base = bases[channel]
            data, kind = fuzzer.mutate(lcm_type, base, [o for o in others if o is not base], now_us)
            reason = predict(lcm_type, data, now_us)
            if reason is None:
                report.skipped += 1
                continue
            client.bus.lcm.publish(channel, data)
            report.sent[channel] += 1
            report.expected[(channel, reason)] += 1
            report.kinds[kind] += 1
            sent += 1
        k += n
        target = total0 + sum(report.sent.values())
        client.wait(
            lambda c, t=target: c.status.num_rejected >= t,
            timeout_s,
            f"the controller to count {target - total0} refused messages",
        )
        if progress is not None:
            progress(report)
    client.wait_time(0.05)  # a status after the last message's count
    report.counted = _counters(client.status) - baseline
    report.seconds = time.monotonic() - start
    return report
