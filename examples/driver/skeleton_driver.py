"""The reference driver of the joint-level protocol (docs/driver.md) in Python, for reading and for
tests: the same perfect position-servoed robot in software as ``skeleton_driver.cc`` (the
measured position is the last commanded one, the velocity the commanded one), the same checks on
commands, watchdog and DRIVER_STATUS.

A Python loop does not hold 1 kHz reliably (the interpreter, its garbage collector, a busy
machine): a robot's driver is written in C++ from ``skeleton_driver.cc``. marionette-controller
runs one tick of 1 ms of controller time per state it takes, so this driver at a lower ``--rate``
runs the control slower than real time, and its deadlines missed show in its exit line.

    export PYTHONPATH=python MARIONETTE_BUILD_DIR=build
    .venv/bin/python examples/driver/skeleton_driver.py --joints a,b,c --rate 250
"""

from __future__ import annotations

import argparse
import math
import select
import signal
import sys
import time
from typing import Any, NoReturn

from marionette import channels, lcmt_driver_command, lcmt_driver_state, lcmt_driver_status
from marionette.lcm_bus import LcmBus


class SkeletonDriver:
    """One robot: the newest valid command, the watchdog, the published state and status."""

    def __init__(
        self,
        bus: LcmBus,
        joints: list[str],
        positions: list[float],
        robot: str,
        command_timeout_s: float,
        wrench_bodies: list[str],
    ) -> None:
        self.bus, self.joints, self.timeout_us = bus, joints, command_timeout_s * 1e6
        self.start = time.monotonic()
        self.q, self.hold_q = list(positions), list(positions)
        self.target_q, self.target_v = list(positions), [0.0] * len(joints)
        self.state = lcmt_driver_state()
        self.state.protocol_version, self.state.robot_name = 1, robot
        self.state.num_joints, self.state.joint_name = len(joints), list(joints)
        self.state.joint_effort = [0.0] * len(joints)  # READ THE JOINT TORQUES HERE
        self.state.base_quaternion = [1.0, 0.0, 0.0, 0.0]  # has_base false: a fixed base
        self.state.num_wrenches, self.state.wrench_body = len(wrench_bodies), list(wrench_bodies)
        self.state.wrench = [[0.0] * 6 for _ in wrench_bodies]  # READ THE F/T SENSORS HERE
        self.status = lcmt_driver_status()
        self.status.robot_name = robot
        self.status.holding, self.status.reason = True, "no command yet"
        self.command: Any = None  # the newest command taken, joints in this driver's order
        self.fresh, self.received_us, self.next_status_us = False, 0, 0
        self.published_holding, self.refused = False, 0
        bus.subscribe(channels.DRIVER_COMMAND, lcmt_driver_command, self.on_command)

    def robot_time(self) -> int:
        """The robot's clock [us]. A REAL ROBOT STAMPS ITS OWN CLOCK HERE."""
        return int((time.monotonic() - self.start) * 1e6)

    def on_command(self, c: Any) -> None:
        # LcmBus checked the bounds before decoding (NaN, sizes, version): refused ones are counted
        # in bus.refusals and never come here.
        if sorted(c.joint_name) != sorted(self.joints):  # by name, in any order
            return self.refuse(f"joints {list(c.joint_name)}, not {self.joints}")
        last = self.command
        if last is not None and (c.sequence <= last.sequence or c.utime <= last.utime):
            return self.refuse(f"out of order: sequence {c.sequence} after {last.sequence}")
        if c.sequence > self.state.sequence:
            return self.refuse("answers a state not yet published")
        index = {name: i for i, name in enumerate(c.joint_name)}
        c.joint_position = [c.joint_position[index[name]] for name in self.joints]
        c.joint_velocity = [c.joint_velocity[index[name]] for name in self.joints]
        self.command, self.fresh, self.received_us = c, True, self.robot_time()
        self.status.commands_taken += 1

    def refuse(self, why: str) -> None:
        self.refused += 1
        self.status.last_refusal = why[:1024]

    def hold(self, now_us: int, reason: str) -> None:
        self.status.reason = reason
        if not self.status.holding:  # ENGAGE THE BRAKES HERE, or servo to hold_q at rest
            self.hold_q, self.status.holding = list(self.q), True
            self.status.holds += 1
            self.status.last_hold_reaction_ms = (now_us - self.received_us) / 1e3

    def cycle(self, now_us: int) -> None:
        """Applies the newest command (or holds), measures, publishes."""
        silent_us = now_us - self.received_us
        if self.command is not None and silent_us >= self.timeout_us:  # the watchdog first
            if not self.status.holding:
                self.hold(now_us, f"no command for {silent_us / 1e3:.1f} ms")
        elif self.fresh and self.command.mode == 1:
            self.hold(now_us, "hold requested")
        elif self.fresh:
            self.status.holding, self.status.reason = False, ""
            self.target_q, self.target_v = self.command.joint_position, self.command.joint_velocity
        if not self.status.holding and self.command.sequence != self.state.sequence:
            self.status.commands_late += 1
        self.fresh = False
        # SEND TO THE SERVOS HERE; READ THE ENCODERS HERE. The perfect robot is at its target.
        self.q = list(self.hold_q if self.status.holding else self.target_q)
        v = [0.0] * len(self.q) if self.status.holding else self.target_v
        self.state.joint_position, self.state.joint_velocity = self.q, list(v)
        self.state.utime, self.state.sequence = now_us, self.state.sequence + 1
        self.bus.publish(channels.DRIVER_STATE, self.state)
        if now_us >= self.next_status_us or self.status.holding != self.published_holding:
            refusals = self.bus.refusals.items()  # + those LcmBus refused before decoding
            bounds = sum(n for (ch, _), n in refusals if ch == channels.DRIVER_COMMAND)
            self.status.utime, self.status.sequence = now_us, self.state.sequence
            self.status.commands_refused = self.refused + bounds
            wall = time.monotonic() - self.start
            self.status.realtime_factor = now_us / 1e6 / wall if wall > 0 else 1.0
            self.bus.publish(channels.DRIVER_STATUS, self.status)
            self.published_holding, self.next_status_us = self.status.holding, now_us + 100_000


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line, exit 2 (as the C++ skeleton)
        print(f"skeleton_driver.py: {message}", file=sys.stderr)
        raise SystemExit(2)


def main(argv: list[str] | None = None) -> int:
    p = _Parser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--joints", required=True, help="the robot's actuated joints: a,b,c")
    p.add_argument("--positions", default="", help="initial positions, one per joint (zeros)")
    p.add_argument("--wrench-bodies", default="", help="bodies whose wrench is measured: a,b")
    p.add_argument("--robot", default="skeleton", help="robot_name in DRIVER_STATE")
    p.add_argument("--lcm-url", default=None, help="default $MARIONETTE_LCM_URL")
    p.add_argument("--rate", type=float, default=1000.0, help="control rate [Hz] (1000)")
    p.add_argument("--command-timeout", type=float, default=0.01, help="watchdog [s] (0.01)")
    p.add_argument("--duration", type=float, default=-1.0, help="robot time [s] (until SIGINT)")
    a = p.parse_args(argv)
    joints = a.joints.split(",")
    if "" in joints or len(set(joints)) != len(joints):
        p.error("--joints: a list of distinct, non-empty names is required")
    try:
        positions = [float(x) for x in a.positions.split(",")] if a.positions else []
    except ValueError:
        p.error(f"--positions: not numbers: {a.positions!r}")
    positions = positions or [0.0] * len(joints)
    if len(positions) != len(joints) or not all(map(math.isfinite, positions)):
        p.error("--positions: one finite value per joint")
    if not 0 < a.rate <= 10_000 or not a.command_timeout > 0:
        p.error("--rate in (0, 10000] and --command-timeout > 0")
    stop: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: stop.append(signum))
    bus = LcmBus(a.lcm_url)
    bodies = a.wrench_bodies.split(",") if a.wrench_bodies else []
    driver = SkeletonDriver(bus, joints, positions, a.robot, a.command_timeout, bodies)
    period, deadline, cycles, missed = 1.0 / a.rate, time.monotonic(), 0, 0
    while not stop:
        now_us = driver.robot_time()
        if 0 <= a.duration <= now_us / 1e6:
            break
        driver.cycle(now_us)
        cycles += 1
        deadline += period  # absolute deadlines; those already past are skipped and counted
        while deadline < time.monotonic():
            deadline, missed = deadline + period, missed + 1
        while not stop and (left := deadline - time.monotonic()) > 0:  # commands as they come
            if select.select([bus.lcm.fileno()], [], [], left)[0]:
                bus.lcm.handle()
    # A REAL DRIVER ENGAGES THE BRAKES HERE before it exits.
    print(f"skeleton_driver.py: {cycles} cycles, {missed} deadlines missed", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
