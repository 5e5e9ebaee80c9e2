"""bench/boundary and bench/lcm_soak: what marionette-controller's LCM boundary costs and does.

micro   the validator and the signature check per message, C++ (marionette-bench-boundary,
        next to lcm-gen's own decode of the same bytes) and Python (the same checks in the
        Python processes)
fuzz    the UR10 kinematic controller, paced at 1 kHz with --realtime (as on a robot): an idle
        run, then N structure-aware mutations (marionette.control.fuzz) on its six input
        channels: sent / refused / crashes per channel, RSS before and after, tick lateness p99
        and deadline misses (from --timing-log) of the idle run and of the fuzz
kill    a supervisor streaming a shoulder swing (0.3 rad, 4 s period) 4 s ahead, killed with
        SIGKILL at a random phase: time from its death to the hold (the journaled tick), joint
        motion between the two, and after the hold

  python -m marionette.control.boundary_benchmark [--messages N] [--idle S] [--trials K]
                                                  [--only micro,fuzz,kill,carry] [--controller BIN]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
import timeit
from functools import partial
from pathlib import Path

import numpy as np

import marionette
import marionette.robots
from marionette import (
    channels,
    lcmt_controller_journal,
    lcmt_controller_status,
    lcmt_object_poses,
    lcmt_robot_command,
    lcmt_robot_state,
    lcmt_supervisor_state,
)
from marionette.control.client import ControllerClient
from marionette.control.fuzz import INPUTS, fuzz_controller, valid_inputs
from marionette.lcm_bus import private_lcm_url
from marionette.lcm_fuzz import random_message
from marionette.lcm_signing import Signer, Verifier
from marionette.lcm_validate import validate
from marionette.processes import ProcessGroup

UR10 = ["--robot", "ur10", "--backend", "kinematic", "--camera-rate", "0"]


def _record_commands_and_holds(
    c: ControllerClient, commands: list[tuple[float, int, np.ndarray]], holds: list[int]
) -> None:
    """Appends every ROBOT_COMMAND (wall time, controller time, joint positions) to ``commands``
    and the tick of every silence hold the controller journals to ``holds``."""
    c.bus.subscribe(
        channels.ROBOT_COMMAND,
        lcmt_robot_command,
        lambda m: commands.append((time.monotonic(), m.utime, np.array(m.joint_position))),
    )
    c.bus.subscribe(
        channels.CONTROLLER_JOURNAL,
        lcmt_controller_journal,
        lambda j: holds.extend(
            t for t, ch in zip(j.tick, j.channel) if ch == "CONTROLLER_SILENCE_HOLD"
        ),
    )


def _controller(group: ProcessGroup, url: str, binary: Path, *args: str) -> ControllerClient:
    proc = group.start("controller", [str(binary), "--lcm-url", url, *UR10, *args])
    client = ControllerClient(url)
    client.wait_ready(120.0, processes=group)
    client.process = proc
    return client


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


# ---- micro ------------------------------------------------------------------------------------


def micro() -> dict:
    binary = marionette.BUILD_DIR / "marionette-bench-boundary"
    out = Path(tempfile.mkdtemp()) / "boundary.json"
    subprocess.run(
        [
            binary,
            "--benchmark_repetitions=5",
            "--benchmark_report_aggregates_only=true",
            "--benchmark_min_time=0.2",
            f"--benchmark_out={out}",
            "--benchmark_out_format=json",
        ],
        check=True,
        capture_output=True,
    )
    cpp = {
        b["run_name"]: b["cpu_time"] * {"ns": 1e-3, "us": 1.0, "ms": 1e3}[b["time_unit"]]
        for b in json.loads(out.read_text())["benchmarks"]
        if b["aggregate_name"] == "median"
    }
    # The same checks in Python, on the controller's input messages.
    now = 10_000_000
    py: dict[str, float] = {}
    for channel, data in valid_inputs(now).items():
        t = INPUTS[channel]
        n = 2000
        py[f"validate {channel}"] = (
            1e6 * timeit.timeit(partial(validate, t, data, now), number=n) / n
        )
    # What the Python processes receive most: TALOS's state (1 kHz in tests), the status (10 Hz).
    rng = random.Random(0)
    for t in (lcmt_robot_state, lcmt_controller_status):
        msg = random_message(t, rng, max_count=0)
        if t is lcmt_robot_state:
            msg.num_joints = 32
            msg.joint_name = [f"arm_left_{i}_joint" for i in range(32)]
            msg.joint_position = msg.joint_velocity = msg.joint_effort = [0.1] * 32
        data = msg.encode()
        n = 2000
        py[f"validate {t.__name__}"] = 1e6 * timeit.timeit(partial(validate, t, data), number=n) / n
        py[f"lcm-gen decode {t.__name__}"] = (
            1e6 * timeit.timeit(partial(t.decode, data), number=n) / n
        )
    message = valid_inputs(now)[channels.TASK_REFERENCE]
    signed = [Signer(b"k" * 32).sign(channels.TASK_REFERENCE, message) for _ in range(2000)]
    verifier = Verifier(b"k" * 32)
    it = iter(signed)
    py[f"verify {len(message)} B"] = (
        1e6
        * timeit.timeit(lambda: verifier.verify(channels.TASK_REFERENCE, next(it)), number=2000)
        / 2000
    )
    return {"cpp_us": cpp, "python_us": py}


# ---- fuzz under a 1 kHz loop --------------------------------------------------------------------


def _ticks(timing_log: Path, first: int, last: int) -> dict:
    t = np.loadtxt(timing_log, delimiter=",", skiprows=1)[first:last]
    lateness = t[:, 2]
    return {
        "ticks": len(t),
        "lateness_p50_us": float(np.percentile(lateness, 50)),
        "lateness_p99_us": float(np.percentile(lateness, 99)),
        "lateness_max_us": float(lateness.max()),
        "deadline_misses": int((lateness > 1000.0).sum()),  # started more than a period late
    }


def fuzz(messages: int, idle_s: float, binary: Path, seed: int = 0, log=print) -> dict:
    url = private_lcm_url()
    log_dir = Path(tempfile.mkdtemp(prefix="boundary-fuzz-"))
    timing_log = log_dir / "timing.csv"
    with ProcessGroup(url, log_dir) as group:
        # As on a robot: the loop at real-time priority (--realtime), so that what the fuzz
        # costs the loop is the boundary's share, not the scheduler's.
        c = _controller(
            group,
            url,
            binary,
            "--realtime",
            "--status-rate",
            "200",
            "--timing-log",
            str(timing_log),
        )
        try:
            c.wait_time(1.0)
            idle0 = c.state.tick
            c.wait_time(idle_s, timeout_s=3 * idle_s + 30)
            idle1 = c.state.tick
            proc = c.process
            assert proc is not None  # _controller sets it
            pid = proc.popen.pid
            rss0 = _rss_mb(pid)
            fuzz0 = c.state.tick

            def progress(r):
                n = sum(r.sent.values())
                if n % 20_000 < 120:
                    log(f"  fuzz: {n} messages, RSS {_rss_mb(pid):.1f} MB")

            report = fuzz_controller(c, messages, random.Random(seed), progress=progress)
            fuzz1 = c.state.tick
            rss1 = _rss_mb(pid)
            alive = proc.alive()
        finally:
            c.close()
        code = group.stop("controller", timeout_s=20.0)
    per_channel = {
        ch: {"sent": sent, "refused": refused, "crashes": 0 if alive and code == 0 else 1}
        for ch, (sent, refused) in report.per_channel().items()
    }
    return {
        "messages": sum(report.sent.values()),
        "seconds": report.seconds,
        "counted_as_predicted": report.counted == report.expected,
        "skipped_still_valid": report.skipped,
        "per_channel": per_channel,
        "reasons": {f"{c}: {r}": n for (c, r), n in sorted(report.counted.items())},
        "kinds": dict(report.kinds),
        "rss_mb": [rss0, rss1],
        "exit_code": code,
        "idle": _ticks(timing_log, idle0, idle1),
        "during_fuzz": _ticks(timing_log, fuzz0, fuzz1),
    }


# ---- a supervisor killed mid-motion -------------------------------------------------------------


def drive(url: str) -> None:
    """The supervisor of the kill trials: a posture spec, the shoulder swinging 0.3 rad with a
    4 s period, streamed 4 s ahead as marionette supervise does (ReferenceStreamer)."""
    from marionette import robots
    from marionette.control.client import configuration_from_state
    from marionette.control.spec import ControllerSpec, TaskSpec
    from marionette.execution.streamer import ReferenceStreamer

    c = ControllerClient(url)
    c.wait_ready(60)
    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    q0 = configuration_from_state(model, c.state)
    cid = int(time.time() * 10) % 1_000_000_000
    spec = [TaskSpec("posture", "posture", 0, gain=10.0, streamed=True)]
    c.send_spec(ControllerSpec(cid, "swing", spec, reference_timeout=0.5))
    c.wait(lambda c: c.status.active_controller_id == cid, 30)
    t = np.arange(60_000) * 1e-3
    w = 2 * np.pi / 4.0
    values = np.tile(q0, (len(t), 1))
    values[:, 0] += 0.3 * np.sin(w * t)
    derivatives = np.zeros((len(t), model.nv))
    derivatives[:, 0] = 0.3 * w * np.cos(w * t)
    streamer = ReferenceStreamer(
        c.send_reference,
        cid,
        {"posture": (values, derivatives)},
        c.utime() + 50_000,
        1000,
        200,
        4.0,
    )
    print("streaming", flush=True)
    while True:
        streamer.pump(c.utime())
        time.sleep(0.005)


def kill_trials(trials: int, binary: Path, seed: int = 0, log=print) -> dict:
    rng = random.Random(seed)
    url = private_lcm_url()
    log_dir = Path(tempfile.mkdtemp(prefix="boundary-kill-"))
    rows = []
    with ProcessGroup(url, log_dir) as group:
        c = _controller(group, url, binary, "--state-rate", "1000", "--status-rate", "100")
        commands: list[tuple[float, int, np.ndarray]] = []
        holds: list[int] = []
        _record_commands_and_holds(c, commands, holds)
        try:
            for trial in range(trials):
                driver = group.start(
                    f"driver{trial}",
                    [sys.executable, "-m", "marionette.control.boundary_benchmark", "--drive", url],
                )
                c.wait(lambda c: c.status.mode == "running", 60, "the driver's controller")
                c.wait_time(1.2 + 4.0 * rng.random())  # armed hold controller; any phase
                n_before = len(holds)
                t_kill = time.monotonic()
                os.kill(driver.popen.pid, signal.SIGKILL)
                driver.popen.wait(10)

                def held(_c: ControllerClient, n: int = n_before) -> bool:
                    return len(holds) > n

                c.wait(held, 10, "the hold")
                c.wait_time(1.5)
                hold_us = holds[-1] * 1000
                snapshot = list(commands)  # the handler thread goes on appending
                recent = [(w, u) for w, u, _ in snapshot if w < t_kill][-2000:]
                offset = min(w - u * 1e-6 for w, u in recent)  # wall - controller time [s]
                kill_us = (t_kill - offset) * 1e6
                utimes = np.array([u for _, u, _ in snapshot])
                q = np.array([q for _, _, q in snapshot])

                def at(u_us: float, utimes=utimes) -> int:  # the command nearest that time
                    return int(np.argmin(np.abs(utimes - u_us)))

                k, h = at(kill_us), at(hold_us)
                dt = max(utimes[k] - utimes[k - 1], 1) * 1e-6
                v_kill = np.abs(q[k] - q[k - 1]).max() / dt
                after = q[(utimes >= hold_us) & (utimes <= hold_us + 1_500_000)]
                q_kill, q_hold = q[k], q[h]
                rows.append(
                    {
                        "kill_to_hold_ms": (hold_us - kill_us) * 1e-3,
                        "reported": c.status.mode_reason.split("; ")[0],
                        "velocity_at_kill_rad_s": float(v_kill),
                        "motion_kill_to_hold_mrad": float(1e3 * np.abs(q_hold - q_kill).max()),
                        "motion_after_hold_mrad": float(
                            1e3 * np.abs(after - q_hold).max(axis=1).max()
                        ),
                        "hold": c.status.mode_reason.split("; ")[-1],
                    }
                )
                log(f"  kill {trial}: {rows[-1]}")
        finally:
            c.close()
    to_hold = np.array([r["kill_to_hold_ms"] for r in rows])
    motion = np.array([r["motion_kill_to_hold_mrad"] for r in rows])
    velocity = np.array([r["velocity_at_kill_rad_s"] for r in rows])
    return {
        "trials": rows,
        "kill_to_hold_ms": {"median": float(np.median(to_hold)), "max": float(to_hold.max())},
        "motion_kill_to_hold_mrad": {
            "median": float(np.median(motion)),
            "max": float(motion.max()),
        },
        "velocity_at_kill_rad_s": {
            "median": float(np.median(velocity)),
            "max": float(velocity.max()),
        },
        "motion_after_hold_mrad": {"max": float(max(r["motion_after_hold_mrad"] for r in rows))},
    }


def carry_kill(binary: Path, log=print) -> dict:
    """The issue's case: `marionette supervise` of the UR10 box plan (MuJoCo, real time) killed
    2 s into the carry, the box in the gripper; then a new `marionette supervise` resumes."""
    from marionette.execution.plan_steps import PlanRobotMap, plan_robot, steps_from_plan
    from marionette.scenarios import SCENARIOS
    from marionette.scenarios.plan_and_execute import PlanAndExecute
    from marionette.scenarios.plan_cache import cached_plan, plan_folder

    scenario = SCENARIOS["ur10-box"]
    assert isinstance(scenario, PlanAndExecute)  # ur10-box plans, then executes
    problem = Path(scenario.problem)
    cache = marionette.REPO_ROOT / "reports" / "plans" / "cache"
    plan = cached_plan(problem, scenario.seed, cache, log)
    plan_json = plan_folder(problem, scenario.seed, cache) / "plan.json"
    robot = plan_robot(plan)
    model, _ = marionette.robots.load_pinocchio(robot, with_collision=False)
    robot_map = PlanRobotMap(plan.doc["problem"]["configuration_layout"], model, robot)
    carry = next(s for s in steps_from_plan(plan) if s.transition.endswith("_34"))
    url = private_lcm_url()
    log_dir = Path(tempfile.mkdtemp(prefix="boundary-carry-"))
    supervise = [sys.executable, "-m", "marionette.cli", "supervise", str(plan_json)]
    supervise += ["--lcm-url", url, "--gripper-admittance"]
    with ProcessGroup(url, log_dir) as group:
        c = ControllerClient(url)
        proc = group.start(
            "controller",
            [str(binary), "--lcm-url", url, "--robot", "ur10", "--scene", str(scenario.scene)]
            + ["--camera-rate", "0", "--state-rate", "1000", "--status-rate", "100"],
        )
        c.wait_ready(60.0, processes=group)
        c.process = proc
        commands: list[tuple[float, int, np.ndarray]] = []
        holds: list[int] = []
        boxes: list[tuple[int, np.ndarray]] = []
        states: list = []
        _record_commands_and_holds(c, commands, holds)
        c.bus.subscribe(
            channels.SIM_OBJECT_POSES,
            lcmt_object_poses,
            lambda m: boxes.extend(
                (m.utime, np.array(o.position_world)) for o in m.objects if o.object_name == "box"
            ),
        )
        c.bus.subscribe(channels.SUPERVISOR_STATE, lcmt_supervisor_state, states.append)
        try:
            q0 = np.array(plan.doc["problem"]["q_init"])
            for name in robot_map.objects:
                c.move_object(name, robot_map.object_pose(q0, name))
            c.wait_time(0.5)
            first = group.start("supervise1", [*supervise, "--specs", str(log_dir / "c1.yaml")])
            c.wait(
                lambda c: (
                    bool(states)
                    and states[-1].step_index == carry.index
                    and states[-1].status == "running"
                ),
                600.0,
                "the carry",
            )
            c.wait_time(2.0)
            t_kill = time.monotonic()
            first.popen.send_signal(signal.SIGKILL)
            first.popen.wait(10)
            c.wait(lambda c: bool(holds), 10.0, "the hold")
            c.wait_time(3.0)
            reason = c.status.mode_reason
            snapshot = list(commands)
            recent = [(w, u) for w, u, _ in snapshot if w < t_kill][-2000:]
            offset = min(w - u * 1e-6 for w, u in recent)
            kill_us = (t_kill - offset) * 1e6
            hold_us = holds[0] * 1000
            utimes = np.array([u for _, u, _ in snapshot])
            q = np.array([q for _, _, q in snapshot])
            k = int(np.argmin(np.abs(utimes - kill_us)))
            h = int(np.argmin(np.abs(utimes - hold_us)))
            after = q[(utimes >= hold_us) & (utimes <= hold_us + 3_000_000)]
            box_u = np.array([u for u, _ in boxes])
            box_p = np.array([p for _, p in boxes])
            kb = int(np.argmin(np.abs(box_u - kill_us)))
            later = box_p[(box_u >= kill_us) & (box_u <= hold_us + 3_000_000)]
            t0 = time.monotonic()
            second = group.start("supervise2", [*supervise, "--specs", str(log_dir / "c2.yaml")])
            code = second.popen.wait(900)
            resumed = second.log_path.read_text()
        finally:
            c.close()
    return {
        "kill_to_hold_ms": (hold_us - kill_us) * 1e-3,
        "hold": reason,
        "joint_motion_kill_to_hold_mrad": float(1e3 * np.abs(q[h] - q[k]).max()),
        "joint_motion_after_hold_mrad": float(1e3 * np.abs(after - q[h]).max()),
        "box_motion_after_kill_mm": float(1e3 * np.linalg.norm(later - box_p[kb], axis=1).max()),
        "resumed_exit_code": code,
        "resumed_wall_s": time.monotonic() - t0,
        "resumed_output": [
            ln for ln in resumed.splitlines() if "starting at" in ln or "supervisor:" in ln
        ],
    }


# ---- report -------------------------------------------------------------------------------------


def _print(results: dict) -> None:
    if "micro" in results:
        cpp, py = results["micro"]["cpp_us"], results["micro"]["python_us"]
        print("per message [us, CPU, median of 5]      validate   lcm-gen decode")
        for name in sorted(k.split("/", 1)[1] for k in cpp if k.startswith("BM_Validate/")):
            print(
                f"  {name:22s}                {cpp['BM_Validate/' + name]:8.2f}   "
                f"{cpp['BM_Decode/' + name]:8.2f}"
            )
        for k in sorted(k for k in cpp if k.startswith("BM_Verify/")):
            print(f"  signature check, {k.split('/')[1]:>6s} B     {cpp[k]:8.2f}")
        print("  Python (the other processes):")
        for k, us in py.items():
            print(f"    {k:40s} {us:8.1f}")
    if "fuzz" in results:
        f = results["fuzz"]
        print(
            f"fuzz: {f['messages']} messages in {f['seconds']:.0f} s, counted as predicted: "
            f"{f['counted_as_predicted']}, exit code {f['exit_code']}; RSS {f['rss_mb'][0]:.1f} "
            f"-> {f['rss_mb'][1]:.1f} MB"
        )
        for ch, r in f["per_channel"].items():
            print(
                f"  {ch:16s} sent {r['sent']:7d}  refused {r['refused']:7d}  crashes {r['crashes']}"
            )
        for phase in ("idle", "during_fuzz"):
            t = f[phase]
            print(
                f"  {phase:12s} {t['ticks']:6d} ticks: lateness p50 "
                f"{t['lateness_p50_us']:6.1f} us, "
                f"p99 {t['lateness_p99_us']:6.1f} us, max {t['lateness_max_us']:7.1f} us, "
                f"{t['deadline_misses']} deadline misses"
            )
    if "kill" in results:
        k = results["kill"]
        print(
            f"supervisor killed ({len(k['trials'])} trials): death -> hold median "
            f"{k['kill_to_hold_ms']['median']:.1f} ms, max {k['kill_to_hold_ms']['max']:.1f} ms; "
            f"joint motion in between median {k['motion_kill_to_hold_mrad']['median']:.1f} mrad, "
            f"max {k['motion_kill_to_hold_mrad']['max']:.1f} mrad (shoulder at up to "
            f"{k['velocity_at_kill_rad_s']['max']:.2f} rad/s); after the hold at most "
            f"{k['motion_after_hold_mrad']['max']:.1f} mrad"
        )
    if "carry" in results:
        k = results["carry"]
        print(
            f"ur10-box supervisor killed mid-carry: death -> hold {k['kill_to_hold_ms']:.1f} ms "
            f"({k['hold']}); joint motion in between "
            f"{k['joint_motion_kill_to_hold_mrad']:.1f} mrad, after "
            f"{k['joint_motion_after_hold_mrad']:.1f} mrad; box moved "
            f"{k['box_motion_after_kill_mm']:.1f} mm; resumed: exit {k['resumed_exit_code']} "
            f"{k['resumed_output']}"
        )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--messages", type=int, default=100_000)
    p.add_argument("--idle", type=float, default=20.0, help="[s] of idle run before the fuzz")
    p.add_argument("--trials", type=int, default=10)
    p.add_argument("--only", default="micro,fuzz,kill,carry")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--controller", type=Path, default=marionette.BUILD_DIR / "marionette-controller"
    )
    p.add_argument("--out", type=Path, default=Path("reports/bench/boundary.json"))
    p.add_argument("--drive", metavar="URL", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.drive:
        drive(args.drive)
        return 0
    only = set(args.only.split(","))
    results: dict = {"load_average": os.getloadavg()}
    if "micro" in only:
        results["micro"] = micro()
    if "fuzz" in only:
        results["fuzz"] = fuzz(args.messages, args.idle, args.controller, args.seed)
    if "kill" in only:
        results["kill"] = kill_trials(args.trials, args.controller, args.seed)
    if "carry" in only:
        results["carry"] = carry_kill(args.controller)
    _print(results)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out}")
    ok = results.get("fuzz", {}).get("counted_as_predicted", True) and all(
        r["crashes"] == 0 for r in results.get("fuzz", {}).get("per_channel", {}).values()
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
