"""bench/driver: the driver boundary's cost and watchdogs (docs/driver.md).

For each robot (TALOS, 38 dofs + free flyer; UR10) under its full stack (the controller benchmark's:
feet and CoM, a streamed hand circle, posture), in real time at 1 kHz on loopback LCM:

* **driver**: ``marionette-sim`` (the robot's driver) + ``marionette-controller --backend driver``.
  The round trip is measured by the driver: from publishing a state to receiving the command that
  answers it (p50 / p99 / max [us]); a *missed cycle* is one whose servos ran on an older command
  (its answer came after 90 % of the period, or never).
* **in-process**: the same stack with MuJoCo in the controller (``--backend mujoco``): its tick's
  compute time and deadline misses, for comparison.

Then the watchdogs, measured on the robot's clock by each side: the driver's hold after the last
command (the controller killed), and the controller's hold after the last state (the driver
stopped with SIGSTOP). Goals: round trip p99 <= 200 us, <= 0.1 % missed cycles, each watchdog
<= its 10 ms + one cycle.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

import marionette
from marionette import channels, lcmt_driver_status, robots
from marionette.control.benchmark import full_stack, hand_links, stream_circle
from marionette.control.client import ControllerClient
from marionette.lcm_bus import LcmBus, private_lcm_url
from marionette.processes import ProcessGroup

ROBOTS = {"talos": "models/scenes/talos_plank.xml", "ur10": "models/scenes/ur10_box.xml"}
WATCHDOG_S = 0.01  # both sides' default


def _stats(x: np.ndarray) -> dict[str, float]:
    return {
        "p50": float(np.median(x)),
        "p99": float(np.percentile(x, 99)),
        "max": float(x.max()),
    }


def _controller(url: str, robot: str, extra: list[str]) -> list[Any]:
    return [
        marionette.BUILD_DIR / "marionette-controller",
        "--lcm-url",
        url,
        "--robot",
        robots.controller_robot_argument(robot),
        "--camera-rate",
        "0",
        *extra,
    ]


def _sim(url: str, robot: str, scene: str, extra: list[str]) -> list[Any]:
    return [
        marionette.BUILD_DIR / "marionette-sim",
        "--lcm-url",
        url,
        "--robot",
        robots.controller_robot_argument(robot),
        "--scene",
        scene,
        "--camera-rate",
        "0",
        *extra,
    ]


def run_case(robot: str, scene: str, split: bool, duration_s: float, work: Path) -> dict[str, Any]:
    """The full stack for ``duration_s`` of robot time, split (driver) or in-process."""
    url = private_lcm_url()
    realtime = ["--realtime"] if os.geteuid() == 0 else []
    name = f"{robot}-{'driver' if split else 'in-process'}"
    ticks_csv, cycles_csv = work / f"{name}-ticks.csv", work / f"{name}-cycles.csv"
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    print(f"  {name}: {duration_s:.0f} s ...", flush=True)
    with ProcessGroup(url, work / name) as group, ControllerClient(url) as client:
        controller_extra = ["--timing-log", str(ticks_csv), *realtime]
        if split:
            group.start(
                "sim", _sim(url, robot, scene, ["--timing-log", str(cycles_csv), *realtime])
            )
            controller_extra += ["--backend", "driver"]
        else:
            controller_extra += ["--scene", scene, "--duration", str(duration_s)]
        proc = group.start("controller", _controller(url, robot, controller_extra))
        client.wait_ready(60, processes=group)
        client.process = proc
        wall_start = time.monotonic()
        client.send_spec(full_stack(robot))
        client.wait(lambda c: c.status.active_controller_id == 1, 30, "the full stack")
        stream_circle(client, model, hand_links(robot)[0], duration_s)
        mode = client.status.mode
        reason = client.status.mode_reason
        if split:
            group.stop("sim", timeout_s=10.0)  # writes its timing log
            group.stop("controller", timeout_s=10.0)
        else:
            proc.popen.wait(timeout=duration_s * 3 + 60)
        wall = time.monotonic() - wall_start
    ticks = np.loadtxt(ticks_csv, delimiter=",", skiprows=1, ndmin=2)
    result: dict[str, Any] = {
        "ticks": len(ticks),
        "compute_us": _stats(ticks[:, 1]),
        "realtime_factor": float(len(ticks) * 1e-3 / wall),
        "mode_at_end": mode,
        "mode_reason_at_end": reason,
    }
    if split:
        cycles = np.genfromtxt(cycles_csv, delimiter=",", skip_header=1, ndmin=2)
        answered = cycles[~np.isnan(cycles[:, 1]), 1]
        result["cycles"] = len(cycles)
        result["round_trip_us"] = _stats(answered)
        result["missed_cycles"] = int(np.sum(cycles[:, 2] > 0))
        result["missed_fraction"] = float(np.mean(cycles[:, 2] > 0))
    else:
        lateness = ticks[1:, 2]
        result["deadline_misses"] = int(np.sum(lateness > 1000.0))
        result["missed_fraction"] = float(np.mean(lateness > 1000.0))
    return result


def watchdogs(robot: str, scene: str, work: Path, repeats: int = 5) -> dict[str, Any]:
    """The driver's hold after the controller is killed; the controller's after the driver stops
    (SIGSTOP), each ``repeats`` times, as each side measures it."""
    driver_ms, controller_ms = [], []
    for i in range(repeats):
        url = private_lcm_url()
        with (
            ProcessGroup(url, work / f"watchdog-{robot}-{i}") as group,
            ControllerClient(url) as client,
            LcmBus(url) as bus,
        ):
            statuses: list[Any] = []
            bus.subscribe(channels.DRIVER_STATUS, lcmt_driver_status, statuses.append)
            bus.start()
            sim = group.start("sim", _sim(url, robot, scene, []))
            controller = group.start("controller", _controller(url, robot, ["--backend", "driver"]))
            client.wait_ready(60, processes=group)
            client.send_spec(full_stack(robot))
            client.wait(lambda c: c.status.mode == "running", 30, "running")
            # The controller's side: the driver stops; the controller says how long it waited.
            os.kill(sim.popen.pid, signal.SIGSTOP)
            client.wait(lambda c: c.status.mode_reason.startswith("driver silent"), 10, "hold")
            controller_ms.append(float(client.status.mode_reason.split("for ")[1].split(" ms")[0]))
            os.kill(sim.popen.pid, signal.SIGCONT)
            time.sleep(0.5)
            # The driver's side: the controller dies; the driver holds on its robot clock.
            controller.popen.kill()
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                if statuses and statuses[-1].holding and statuses[-1].last_hold_reaction_ms > 0:
                    break
                time.sleep(0.05)
            driver_ms.append(float(statuses[-1].last_hold_reaction_ms))
    return {
        "driver_hold_after_last_command_ms": driver_ms,
        "controller_hold_after_last_state_ms": controller_ms,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=float(os.environ.get("MARIONETTE_BENCH_DURATION", 600)),
        help="seconds of robot time per case (default 600, or $MARIONETTE_BENCH_DURATION)",
    )
    parser.add_argument("--robots", nargs="+", default=list(ROBOTS), choices=list(ROBOTS))
    parser.add_argument(
        "--out", type=Path, default=marionette.REPO_ROOT / "reports" / "bench" / "driver.json"
    )
    args = parser.parse_args(argv)
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for robot in args.robots:
            scene = str(marionette.REPO_ROOT / ROBOTS[robot])
            results[robot] = {
                "driver": run_case(robot, scene, True, args.duration, work),
                "in-process": run_case(robot, scene, False, args.duration, work),
                "watchdogs": watchdogs(robot, scene, work),
            }
    rt = "on" if os.geteuid() == 0 else "refused: not root"
    print(
        f"\nfull stack at 1 kHz, {args.duration:.0f} s per case, loopback LCM, this machine "
        f"({os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}); --realtime {rt}"
    )
    print(
        f"{'robot':6} {'case':11} {'round trip p50/p99/max [us]':>28} {'compute p50/p99 [us]':>21} "
        f"{'missed':>14} {'RTF':>6}"
    )
    for robot, r in results.items():
        d, p = r["driver"], r["in-process"]
        rtt = d["round_trip_us"]
        print(
            f"{robot:6} {'driver':11} {rtt['p50']:8.0f} {rtt['p99']:8.0f} {rtt['max']:9.0f}   "
            f"{d['compute_us']['p50']:8.0f} {d['compute_us']['p99']:8.0f}   "
            f"{d['missed_cycles']:6d} {100 * d['missed_fraction']:5.2f}% "
            f"{d['realtime_factor']:6.3f}"
        )
        print(
            f"{robot:6} {'in-process':11} {'-':>28}   "
            f"{p['compute_us']['p50']:8.0f} {p['compute_us']['p99']:8.0f}   "
            f"{p['deadline_misses']:6d} {100 * p['missed_fraction']:5.2f}% "
            f"{p['realtime_factor']:6.3f}"
        )
        w = r["watchdogs"]
        goal = 1e3 * WATCHDOG_S + 1.0
        for key, label in (
            ("driver_hold_after_last_command_ms", "driver holds after the last command"),
            ("controller_hold_after_last_state_ms", "controller holds after the last state"),
        ):
            ms = w[key]
            verdict = "met" if max(ms) <= goal else "MISSED"
            print(
                f"{robot:6} {label}: {min(ms):.1f}-{max(ms):.1f} ms over {len(ms)} "
                f"(goal <= {goal:.0f} ms: {verdict})"
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
