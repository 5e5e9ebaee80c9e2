"""bench/controller: marionette-controller's loop timing on long runs.

A robot (``--robot``, in its ``--scene``) in MuJoCo under its full stack — [feet, CoM] > [first
gripper moving, second gripper relative to the first] > [posture], with joint limits (the feet and
the CoM for a robot with feet; the second gripper when it has one) — with the head camera on
(30 Hz, 640x480), with it off, and the same stack on the kinematic backend. Every tick's timing is
logged by the controller
(--timing-log); the figures are computed over the whole run: compute time and lateness
p50 / p99 / max, deadline misses (ticks starting more than one period late), and the real-time
factor (controller time / wall time).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

import marionette
from marionette import robots
from marionette.control.client import ControllerClient, configuration_from_state, pose_to_vector
from marionette.control.spec import ControllerSpec, TaskSpec, reference_chunk
from marionette.lcm_bus import private_lcm_url
from marionette.processes import ProcessGroup


def hand_links(robot: str) -> list[str]:
    """The links of the robot's grippers, in robot.yaml's order, without repeats."""
    return list(dict.fromkeys(g.link for g in robots.semantics(robot).grippers))


def full_stack(robot: str) -> ControllerSpec:
    desc = robots.robot(robot)
    hands = hand_links(robot)
    tasks = [TaskSpec(f"foot_{f.name}", "se3", 0, frame=f.frame, gain=10.0) for f in desc.feet]
    if desc.feet:
        tasks.append(TaskSpec("com", "com", 0, gain=10.0))
    tasks.append(TaskSpec("hand", "se3", 1, frame=hands[0], gain=5.0, streamed=True))
    if len(hands) > 1:
        tasks.append(
            TaskSpec("other_hand", "relative_se3", 1, frame=hands[1], frame_b=hands[0], gain=5.0)
        )
    tasks.append(TaskSpec("posture", "posture", 2, gain=1.0))
    return ControllerSpec(
        1, "full_stack", tasks, max_switch_velocity_jump=0.1, reference_timeout=0.5
    )


def stream_circle(client: ControllerClient, model, hand: str, duration_s: float) -> None:
    """Streams the ``hand`` link along a 5 cm circle (period 4 s), 1 s ahead, until the end."""
    data = model.createData()
    q = configuration_from_state(model, client.state)
    pin.framesForwardKinematics(model, data, q)
    X0 = pin.SE3(data.oMf[model.getFrameId(hand)])
    proc = client.process
    if proc is None:
        raise ValueError("stream_circle: client.process is not set (the controller's process)")
    start = client.utime()
    sent_until = start
    while client.utime() < start + duration_s * 1e6 and proc.alive():
        while sent_until < client.utime() + 1_000_000:
            t = (sent_until - start) * 1e-6 + 1e-3 * np.arange(200)
            w = 2 * np.pi / 4.0
            offsets = 0.05 * np.stack([np.zeros_like(t), np.sin(w * t), 1 - np.cos(w * t)], axis=1)
            rates = 0.05 * w * np.stack([np.zeros_like(t), np.cos(w * t), np.sin(w * t)], axis=1)
            values = np.array(
                [pose_to_vector(pin.SE3(X0.rotation, X0.translation + o)) for o in offsets]
            )
            derivatives = np.hstack([rates, np.zeros((len(t), 3))])
            client.send_reference(reference_chunk(1, "hand", sent_until, values, derivatives))
            sent_until += 200_000
        time.sleep(0.05)


def run(robot: str, name: str, args: list[str], duration_s: float, log_dir: Path) -> dict:
    url = private_lcm_url()
    binary = marionette.BUILD_DIR / "marionette-controller"
    timing_log = log_dir / f"{name}.csv"
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    print(f"  {' '.join(map(str, args))}: {duration_s:.0f} s of controller time ...", flush=True)
    with ProcessGroup(url, log_dir / name) as group, ControllerClient(url) as client:
        proc = group.start(
            "controller",
            [
                str(binary),
                "--robot",
                robots.controller_robot_argument(robot),
                "--lcm-url",
                url,
                "--duration",
                str(duration_s),
                "--timing-log",
                str(timing_log),
                *args,
            ],
        )
        client.wait_ready(60)
        client.process = proc
        wall_start = time.monotonic()
        client.send_spec(full_stack(robot))
        client.wait(lambda c: c.status.active_controller_id == 1, 30, "the full stack")
        stream_circle(client, model, hand_links(robot)[0], duration_s)
        proc.popen.wait(timeout=duration_s * 3 + 60)
        wall = time.monotonic() - wall_start
        errors = dict(zip(client.status.task_name, client.status.task_error_norm))
        mode = client.status.mode
    t = np.loadtxt(timing_log, delimiter=",", skiprows=1)
    period, compute, lateness = t[1:, 0], t[:, 1], t[1:, 2]

    def stats(x):
        return {
            "p50": float(np.median(x)),
            "p99": float(np.percentile(x, 99)),
            "max": float(x.max()),
        }

    return {
        "ticks": len(t),
        "compute_us": stats(compute),
        "lateness_us": stats(lateness),
        "period_us": stats(period),
        "deadline_misses": int(np.sum(lateness > 1000.0)),
        "realtime_factor": float(len(t) * 1e-3 / wall),
        "mode_at_end": mode,
        "task_errors_at_end": errors,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--robot", required=True, help="robot name or folder")
    parser.add_argument("--scene", type=Path, required=True, help="MJCF scene with the robot")
    parser.add_argument(
        "--duration", type=float, default=float(os.environ.get("MARIONETTE_BENCH_DURATION", 600))
    )
    parser.add_argument(
        "--out", type=Path, default=marionette.REPO_ROOT / "reports" / "bench" / "controller.json"
    )
    parser.add_argument(
        "--only",
        action="append",
        default=[],
        metavar="TEXT",
        help="run only the cases whose name contains TEXT (repeatable)",
    )
    args = parser.parse_args(argv)
    scene = str(args.scene)
    realtime = ["--realtime"] if os.geteuid() == 0 else []
    cases = {
        "mujoco + camera 30 Hz": ["--scene", scene, "--camera-rate", "30", *realtime],
        "mujoco, camera off": ["--scene", scene, "--camera-rate", "0", *realtime],
        "kinematic": ["--backend", "kinematic", "--camera-rate", "0", *realtime],
        "mujoco + camera, no RT": ["--scene", scene, "--camera-rate", "30"],
    }
    if args.only:
        cases = {n: c for n, c in cases.items() if any(t in n for t in args.only)}
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, extra) in enumerate(cases.items()):
            results[name] = run(args.robot, f"case{i}", extra, args.duration, Path(tmp))
    rt = "on" if realtime else "refused: not root"
    print(
        f"\n{args.robot} full stack, {args.duration:.0f} s each, 1 kHz, this machine (2 cores), "
        f"load {os.getloadavg()[0]:.1f}; --realtime (SCHED_FIFO + mlockall) {rt}"
    )
    print(
        f"{'case':24} {'compute p50/p99/max [us]':>28} {'lateness p50/p99/max [us]':>28} "
        f"{'misses':>7} {'RTF':>6}"
    )
    for name, r in results.items():
        c, l = r["compute_us"], r["lateness_us"]
        print(
            f"{name:24} {c['p50']:8.0f} {c['p99']:8.0f} {c['max']:9.0f}   "
            f"{l['p50']:8.0f} {l['p99']:8.0f} {l['max']:9.0f}   {r['deadline_misses']:6d} "
            f"{r['realtime_factor']:6.3f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
