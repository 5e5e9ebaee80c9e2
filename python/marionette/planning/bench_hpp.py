"""Planning benchmarks against HPP 9.0.2 in the same run (entry point of bench/planning_vs_hpp).

For each problem: the problem is exported for HPP (``hpp_export``), then seeds run in
alternating blocks (an HPP block in its own interpreter, ``--hpp-python`` running
``bench/hpp_side.py``, then a marionette block) so that both see the same machine load.  Both
sides plan each seed from scratch with the same iteration and time limits (HPP's roadmap and
ours are built, the graph initialised, before timing); a guided problem is planned leg by leg
through the same waypoints on both sides.  Then each solution is optimised (HPP's
RandomShortcut; ``optimize.optimize_paths``) and its arm path length measured the same way
(sum of |delta q| over the robot's 1-dof joints, sampled every 0.01 of the path parameter).

HPP plans with contact only (no security margins are set on its side), so marionette's free
motions do too by default (``--clearance 0``; the product's default keeps 1 cm from still bodies,
``planner.clearance``): the comparison is like for like. ``--clearance 0.01`` measures what that
caution costs.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

import marionette
from marionette.planning.collision import CollisionChecker
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.guide import guide_configuration, plan_through
from marionette.planning.hpp_export import arm_indices, hpp_description
from marionette.planning.optimize import arm_path_length, optimize_paths
from marionette.planning.planner import ManipulationRRT
from marionette.planning.problem import ManipulationProblem, load_problem

PROBLEMS = {
    "ur5_box": marionette.REPO_ROOT / "bench" / "ur5_box" / "problem.yaml",
    "ur5_box_wall": marionette.REPO_ROOT / "bench" / "ur5_box_wall" / "problem.yaml",
    "ur10_swap": Path(__file__).parent / "problems" / "ur10_swap.yaml",
    "ur10_tower": Path(__file__).parent / "problems" / "ur10_tower.yaml",
    "talos_plank": Path(__file__).parent / "problems" / "talos_plank.yaml",
}


def legs(problem: ManipulationProblem, graph, checker) -> list[tuple[np.ndarray, np.ndarray]]:
    """init -> goal, or init -> guide waypoints -> goal (waypoints of seed 0: the same for
    every seed and for both planners)."""
    guide = problem.settings.get("guide") or []
    rng = np.random.default_rng(0)
    q_init, q_goal = problem.require_init(), problem.require_goal()
    points = [guide_configuration(problem, graph, checker, e, q_init, rng) for e in guide]
    chain = [q_init, *points, q_goal]
    return list(zip(chain, chain[1:]))


def run_marionette(problem, graph, checker, chain, seed, max_iterations, timeout, optimize):
    """One seed: planning time, success, nodes; arm path length before / after optimisation."""
    t0 = time.perf_counter()
    if len(chain) == 1:
        planner = ManipulationRRT(problem, graph, checker, seed=seed)
        r = planner.solve(chain[0][0], [chain[0][1]], max_iterations, timeout)
    else:
        configs = [chain[0][0]] + [b for _, b in chain]
        r = plan_through(problem, graph, checker, configs, seed, max_iterations, timeout)
    out = {
        "seed": seed,
        "success": r.success,
        "time_s": time.perf_counter() - t0,
        "nodes": r.nodes,
    }
    if r.success and optimize:
        arm = arm_indices(problem)
        out["raw_arm_length"] = arm_path_length(r.paths, arm)
        t1 = time.perf_counter()
        paths = optimize_paths(r.paths, graph, checker, np.random.default_rng(seed))
        out["optimize_s"] = time.perf_counter() - t1
        out["arm_length"] = arm_path_length(paths, arm)
    return out


def _hpp_block(args, spec_file: Path, first: int, last: int) -> list[dict]:
    """HPP on seeds first..last; a crashed interpreter (HPP segfaults now and then) costs its
    seed a failure and the block goes on, one seed per interpreter."""
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = f"{args.hpp_prefix}/lib:" + env.get("LD_LIBRARY_PATH", "")
    env["ROS_PACKAGE_PATH"] = f"{args.hpp_prefix}/share"

    def run(a: int, b: int) -> list[dict] | None:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "hpp.json"
            cmd = [
                args.hpp_python,
                str(args.hpp_script),
                str(spec_file),
                "--seeds",
                str(a),
                str(b),
                "--max-iterations",
                str(args.max_iterations),
                "--timeout",
                str(args.timeout),
                "--out",
                str(out),
            ] + (["--optimize"] if args.optimize else [])
            proc = subprocess.run(cmd, env=env, timeout=3600 + 2 * args.timeout * (b - a + 1))
            if proc.returncode != 0 or not out.exists():
                return None
            return json.loads(out.read_text())["runs"]

    runs = run(first, last)
    if runs is not None:
        return runs
    runs = []
    for s in range(first, last + 1):
        one = run(s, s)
        runs += one or [
            {"seed": s, "success": False, "time_s": args.timeout, "nodes": 0, "crashed": True}
        ]
    return runs


def summary(runs: list[dict]) -> dict[str, float]:
    """Success rate, median / p90 planning time [ms] (every run, failures at their time),
    median roadmap nodes, median arm path length raw and optimised (successes)."""
    t = np.array([r["time_s"] for r in runs if np.isfinite(r["time_s"])]) * 1e3
    ok = np.array([r["success"] for r in runs], dtype=bool)

    def med(key):
        v = [r[key] for r in runs if key in r]
        return float(np.median(v)) if v else float("nan")

    return {
        "runs": len(runs),
        "success_rate": float(ok.mean()) if len(runs) else 0.0,
        "median_ms": float(np.median(t)) if len(t) else float("nan"),
        "p90_ms": float(np.percentile(t, 90)) if len(t) else float("nan"),
        "median_nodes": med("nodes"),
        "median_raw_arm_length": med("raw_arm_length"),
        "median_arm_length": med("arm_length"),
        "crashed": sum(bool(r.get("crashed")) for r in runs),
    }


def _paired_ratio(hpp: list[dict], mar: list[dict], key: str) -> float:
    """Median over seeds both solved of marionette's / HPP's value of ``key``."""
    h = {r["seed"]: r[key] for r in hpp if key in r}
    m = {r["seed"]: r[key] for r in mar if key in r}
    common = sorted(set(h) & set(m))
    return float(np.median([m[s] / h[s] for s in common])) if common else float("nan")


def bench_problem(name: str, args) -> dict:
    problem = load_problem(PROBLEMS[name])
    problem.settings["planner"] = {
        **(problem.settings.get("planner") or {}),
        "clearance": args.clearance,
    }
    graph = graph_from_settings(problem)
    graph.initialize()
    checker = CollisionChecker(problem)
    chain = legs(problem, graph, checker)
    hpp_runs, mar_runs = [], []
    seeds = list(range(1, args.seeds + 1))  # HPP's seeds 0 and 1 behave alike: start at 1
    with tempfile.TemporaryDirectory() as tmp:
        spec_file = Path(tmp) / f"{name}.json"
        spec_file.write_text(json.dumps(hpp_description(problem, chain)))
        for k in range(0, len(seeds), args.block):
            block = seeds[k : k + args.block]
            hpp_runs += _hpp_block(args, spec_file, block[0], block[-1])
            mar_runs += [
                run_marionette(
                    problem,
                    graph,
                    checker,
                    chain,
                    s,
                    args.max_iterations,
                    args.timeout,
                    args.optimize,
                )
                for s in block
            ]
            print(
                f"  {name} seeds {block[0]}-{block[-1]}: HPP "
                f"{summary(hpp_runs[-len(block) :])['median_ms']:.0f} ms, marionette "
                f"{summary(mar_runs[-len(block) :])['median_ms']:.0f} ms (block medians)",
                flush=True,
            )
    hs, ms = summary(hpp_runs), summary(mar_runs)
    return {
        "problem": name,
        "legs": len(chain),
        "hpp": {"summary": hs, "runs": hpp_runs},
        "marionette": {"summary": ms, "runs": mar_runs},
        "paired_arm_length_ratio": _paired_ratio(hpp_runs, mar_runs, "arm_length"),
    }


def print_table(results: list[dict], seeds: int, clearance: float) -> None:
    print(
        f"\nPlanning vs HPP 9.0.2, {seeds} seeds per problem, same machine, alternating blocks; "
        f"marionette's free motions keep {clearance * 1e3:g} mm from still bodies (HPP: contact)"
    )
    head = (
        f"{'problem':14s}{'HPP ok':>8s}{'ours ok':>8s}{'HPP med ms':>12s}{'ours med ms':>12s}"
        f"{'ratio':>7s}{'HPP p90':>9s}{'ours p90':>9s}{'HPP arm':>9s}{'ours arm':>9s}"
        f"{'paired':>8s}"
    )
    print(head)
    for r in results:
        h, m = r["hpp"]["summary"], r["marionette"]["summary"]
        ratio = m["median_ms"] / h["median_ms"] if h["median_ms"] else float("nan")
        print(
            f"{r['problem']:14s}{h['success_rate']:>8.0%}{m['success_rate']:>8.0%}"
            f"{h['median_ms']:>12.1f}{m['median_ms']:>12.1f}{ratio:>7.2f}{h['p90_ms']:>9.0f}"
            f"{m['p90_ms']:>9.0f}{h['median_arm_length']:>9.2f}{m['median_arm_length']:>9.2f}"
            f"{r['paired_arm_length_ratio']:>8.2f}"
        )
    print(
        "ok: success rate; med / p90: planning time over every seed (a failure counts its time);"
        "\narm: median arm path length [rad] after optimisation (HPP: RandomShortcut) over solved"
        " seeds;\npaired: median over seeds both solved of ours / HPP's arm length."
    )
    for r in results:
        runs = r["hpp"]["runs"]
        unposed = {x["error"] for x in runs if x.get("not_posed")}
        if unposed:
            print(f"HPP could not pose {r['problem']}: {'; '.join(sorted(unposed))}")
            continue
        # HPP's messages carry times and counts: grouped with their numbers blanked
        failures = Counter(re.sub(r"\d+(\.\d+)?", "#", x["error"]) for x in runs if "error" in x)
        if failures:
            said = "; ".join(f"{n}x {msg}" for msg, n in failures.most_common())
            print(f"HPP's failed seeds on {r['problem']}: {said}")
    crashed = {r["problem"]: r["hpp"]["summary"]["crashed"] for r in results}
    if any(crashed.values()):
        print(f"HPP crashes (counted as failures at the time limit): {crashed}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=list(PROBLEMS))
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--block", type=int, default=5, help="seeds per alternating block")
    ap.add_argument("--max-iterations", type=int, default=5000)
    ap.add_argument("--timeout", type=float, default=60.0, help="per seed [s]")
    ap.add_argument("--no-optimize", dest="optimize", action="store_false")
    ap.add_argument(
        "--clearance",
        type=float,
        default=0.0,
        help="m kept from still bodies on free motions (default 0: contact only, as HPP)",
    )
    ap.add_argument("--hpp-python", required=True)
    ap.add_argument("--hpp-prefix", required=True)
    ap.add_argument(
        "--hpp-script", type=Path, default=marionette.REPO_ROOT / "bench" / "hpp_side.py"
    )
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    if args.seeds < 1 or args.block < 1:
        ap.error("--seeds and --block must be >= 1")
    results = []
    for name in args.problems:
        results.append(bench_problem(name, args))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1))
    print_table(results, args.seeds, args.clearance)
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
