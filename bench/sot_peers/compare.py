"""Runs the sot benchmark and its peers in one run, prints medians / p99 / ratios, writes JSON.

    python compare.py --ours BIN --tsid BIN --pink-python PY [--ticks N] [--rounds R]
                      [--out FILE]

1. `--ours` (marionette-bench-sot) times the TALOS reference stack and prints, per scenario, the
   model files and the reach it used;
2. for every scenario with joint limits (nominal, bounds_binding), the same stack is run in
   TSID (`--tsid`, marionette-bench-sot-tsid, C++), with the same model files, reach, gains and
   tick count; 1 and 2 alternate `--rounds` times (a shared machine's speed drifts by tens of
   % within a minute: the ratio of one round compares two moments), and the ratio to TSID is
   the median of the rounds' ratios;
3. pink (pink_bench.py under `--pink-python`) runs once per scenario;
4. prints one table per scenario (the round whose nominal ratio is the median) and the ratios
   ours / peer of the median and p99 of the per-tick solve path (ours: kinematics + tasks +
   solve; TSID: bounds + computeProblemData + QP; pink: configuration.update + solve_ik), and
   writes everything to `--out`.
Only the standard library: runs under any Python 3.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import statistics
import subprocess
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent
PEER_SCENARIOS = ("nominal", "bounds_binding")  # the scenarios with joint limits
# The targets for our whole tick (kinematics + solve) with the joint bounds: absolute, against
# TSID's median in the same run, and the tail against our own median.
TARGET_MEDIAN_US, TARGET_P99_US, TARGET_RATIO_TSID, TARGET_P99_OVER_MEDIAN = 50.0, 100.0, 0.3, 2.0


def run_json(cmd: list[str], what: str) -> dict:
    """Runs `cmd`, returns the JSON object it prints last; exits with its stderr on failure."""
    started = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"[sot bench] {what} failed (exit {proc.returncode}):\n{proc.stderr[-2000:]}")
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    try:
        text = proc.stdout[proc.stdout.index("{") :]
        result = json.loads(text)
    except (ValueError, json.JSONDecodeError):
        sys.exit(f"[sot bench] {what} printed no JSON:\n{(lines or [''])[-1][:500]}")
    print(f"[sot bench] {what}: {time.monotonic() - started:.1f} s", file=sys.stderr)
    return result


def ratio(a: float, b: float) -> float | None:
    return a / b if b > 0 else None


def median(values: list[float | None]) -> float | None:
    """The median of the known values (the lower one of the middle two, if even)."""
    known = [v for v in values if v is not None]
    return statistics.median_low(known) if known else None


def peer_arguments(model: dict, args: argparse.Namespace) -> list[str]:
    """The model files, tick count and posture weight every peer is given."""
    return [
        "--urdf",
        model["urdf"],
        "--srdf",
        model["srdf"],
        "--ticks",
        str(args.ticks),
        "--posture-weight",
        repr(args.posture_weight),
    ]


def scenario_arguments(ours: dict, scenario: str) -> list[str]:
    """The scenario and the reach marionette used in it."""
    return ["--scenario", scenario, "--reach", *[repr(x) for x in ours[scenario]["reach"]]]


def fmt_ratio(r: float | None) -> str:
    return "-" if r is None else f"{r:.2f}x"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ours", required=True, help="marionette-bench-sot executable")
    p.add_argument("--tsid", required=True, help="marionette-bench-sot-tsid executable")
    p.add_argument("--pink-python", required=True, help="python of the venv with pink + daqp")
    p.add_argument("--ticks", type=int, default=20000)
    p.add_argument(
        "--posture-weight",
        type=float,
        default=1e-5,
        help="peers' posture weight relative to the grippers (two-level QPs)",
    )
    p.add_argument(
        "--rounds",
        type=int,
        default=3,
        help="marionette and TSID alternate this many times; ratio = median of the rounds'",
    )
    p.add_argument("--out", default="reports/bench/sot.json")
    args = p.parse_args(argv)
    if args.ticks < 10000:
        p.error(f"--ticks must be >= 10000 (got {args.ticks})")
    if args.rounds < 1:
        p.error(f"--rounds must be >= 1 (got {args.rounds})")
    for exe in (args.ours, args.tsid, args.pink_python):
        if not pathlib.Path(exe).exists():
            p.error(f"not found: {exe}")

    rounds: list[tuple[dict, dict]] = []  # (ours, TSID per scenario)
    for k in range(args.rounds):
        tag = f"round {k + 1}/{args.rounds}"
        ours = run_json([args.ours, "--ticks", str(args.ticks)], f"marionette (C++) {tag}")
        model = ours.pop("model")
        tsid = {}
        for scenario in PEER_SCENARIOS:
            tsid[scenario] = run_json(
                [args.tsid, *peer_arguments(model, args), *scenario_arguments(ours, scenario)],
                f"TSID (C++) {scenario} {tag}",
            )[scenario]
        rounds.append((ours, tsid))
    round_ratios = [
        {sc: ratio(o[sc]["solve_path"]["median"], t[sc]["tick"]["median"]) for sc in PEER_SCENARIOS}
        for o, t in rounds
    ]
    by_nominal = sorted(range(len(rounds)), key=lambda k: round_ratios[k]["nominal"] or 1e9)
    ours, tsid = rounds[by_nominal[(len(rounds) - 1) // 2]]  # the median round (lower, if even)
    peers: dict[str, dict] = {"tsid": tsid, "pink": {}}
    for scenario in PEER_SCENARIOS:
        peers["pink"][scenario] = run_json(
            [
                args.pink_python,
                str(HERE / "pink_bench.py"),
                *peer_arguments(model, args),
                *scenario_arguments(ours, scenario),
            ],
            f"pink (Python) {scenario}",
        )[scenario]

    ratios: dict[str, dict] = {}
    print(f"\nsot: TALOS talos_reduced (nv 38), {args.ticks} ticks at 1 kHz after 500 warm-up; µs")
    for scenario in ("nominal", "equality_only", "bounds_binding"):
        o = ours[scenario]
        print(
            f"\n  {scenario}  (reach {o['reach']}, joint limits {o['joint_limits']}, "
            f"QP ticks {o['qp_ticks']})"
        )
        print(f"  {'':34s}{'median':>9s}{'p99':>10s}   hand err [m]  max foot err")
        row = "  {:34s}{:9.1f}{:10.1f}   {:12.2e}  {:12.2e}"
        print(
            row.format(
                "marionette solve path (kin+tasks+solve)",
                o["solve_path"]["median"],
                o["solve_path"]["p99"],
                o["final_hand_position_error"],
                o["max_foot_error"],
            )
        )
        for phase in ("kinematics", "tasks", "solve", "tick_uninstrumented"):
            print(f"  {'  ' + phase:34s}{o[phase]['median']:9.1f}{o[phase]['p99']:10.1f}")
        if scenario not in PEER_SCENARIOS:
            continue
        ratios[scenario] = {}
        tsid_rounds = [rr[scenario] for rr in round_ratios]
        for name, label, parts in (
            ("tsid", "TSID 1.10 C++ (data+QP)", ("kinematics", "problem_data", "solve")),
            ("pink", "pink 4.4 + daqp (Python)", ("kinematics", "solve")),
        ):
            r = peers[name][scenario]
            print(
                row.format(
                    label,
                    r["tick"]["median"],
                    r["tick"]["p99"],
                    r["final_hand_position_error"],
                    r["max_foot_error"],
                )
            )
            for phase in parts:
                print(f"  {'  ' + phase:34s}{r[phase]['median']:9.1f}{r[phase]['p99']:10.1f}")
            ratios[scenario][name] = {
                "median": median(tsid_rounds)
                if name == "tsid"
                else ratio(o["solve_path"]["median"], r["tick"]["median"]),
                "p99": ratio(o["solve_path"]["p99"], r["tick"]["p99"]),
                "solve_only_median": ratio(o["solve"]["median"], r["solve"]["median"]),
            }
            if r.get("qp_failures"):
                print(f"  !! {name}: {r['qp_failures']} QP failures")
        rt, rp = ratios[scenario]["tsid"], ratios[scenario]["pink"]
        rt["rounds"] = tsid_rounds
        print(
            f"  ratio marionette / TSID: median {fmt_ratio(rt['median'])} (median of "
            f"{len(rounds)} rounds: {', '.join(fmt_ratio(x) for x in rt['rounds'])}), p99 "
            f"{fmt_ratio(rt['p99'])}, solver alone {fmt_ratio(rt['solve_only_median'])}; "
            f"/ pink: median {fmt_ratio(rp['median'])}, p99 {fmt_ratio(rp['p99'])}"
        )

    n = ours["nominal"]["solve_path"]
    targets = {
        "median_us": TARGET_MEDIAN_US,
        "p99_us": TARGET_P99_US,
        "ratio_tsid": TARGET_RATIO_TSID,
        "met_median": n["median"] <= TARGET_MEDIAN_US,
        "met_p99": n["p99"] <= TARGET_P99_US,
        "met_ratio": (ratios["nominal"]["tsid"]["median"] or 1e9) <= TARGET_RATIO_TSID,
        "p99_over_median": TARGET_P99_OVER_MEDIAN,
        "met_p99_over_median": n["p99"] <= TARGET_P99_OVER_MEDIAN * n["median"],
    }
    print(
        f"\n  targets (nominal): median <= {TARGET_MEDIAN_US:g} µs "
        f"{'met' if targets['met_median'] else 'MISSED'}, p99 <= {TARGET_P99_US:g} µs "
        f"{'met' if targets['met_p99'] else 'MISSED'}, <= {TARGET_RATIO_TSID:g}x TSID "
        f"{'met' if targets['met_ratio'] else 'MISSED'}, p99 <= {TARGET_P99_OVER_MEDIAN:g}x "
        f"median {'met' if targets['met_p99_over_median'] else 'MISSED'}"
    )
    report = {
        "benchmark": "sot",
        "unit": "us",
        "ticks": args.ticks,
        "rounds": [{"marionette": o, "tsid": t} for o, t in rounds],
        "model": model,
        "peer_posture_weight": args.posture_weight,
        "machine": {
            "cpus": __import__("os").cpu_count(),
            "platform": platform.platform(),
            "load_average": list(__import__("os").getloadavg()),
        },
        "marionette": ours,
        "tsid": peers["tsid"],
        "pink": peers["pink"],
        "ratios_marionette_over_peer": ratios,
        "targets": targets,
        "included": {
            "marionette": "RobotModel (forwardKinematics, frame placements, joint Jacobians, CoM "
            "+ CoM Jacobian), 7 features + 7 tasks, strict-hierarchy Solver "
            "(joint limits level 0, 3 equality levels, smooth-switching blend)",
            "tsid": "joint-bound box update, computeProblemData (Pinocchio computeAllTerms incl. "
            "mass matrix and nonlinear effects, 7 tasks), eiquadprog-fast QP",
            "pink": "Configuration.update (computeJointJacobians, updateFramePlacements), "
            "solve_ik (6 tasks, configuration + velocity limits, qpsolvers + daqp), "
            "Python overhead included",
        },
    }
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1) + "\n")
    print(f"\n  written: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
