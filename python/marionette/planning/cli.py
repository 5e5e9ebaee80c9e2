"""``marionette plan <problem.yaml>``: build the graph, plan, shorten, write plan + graph picture."""

from __future__ import annotations

import argparse
import difflib
import sys
import time
from pathlib import Path

import numpy as np


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "plan",
        help="plan a manipulation problem with Manipulation-RRT over its constraint graph",
        description="Plan a manipulation problem (YAML) and write the plan (<out>/plan.json + "
        "plan.npz, format marionette-plan/1) and the constraint graph (graph.png).",
        epilog="examples:\n"
        "  marionette plan ur10_box                      # a bundled problem, by name\n"
        "  marionette plan my_problem.yaml --seed 3 --out plans/mine\n"
        "  marionette plan talos_plank --timeout 120 --quiet",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "problem",
        type=Path,
        help="problem file (YAML), or the name of a bundled problem "
        "(python/marionette/planning/problems/<name>.yaml, e.g. ur10_box)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default: reports/plans/<problem name>)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-iterations", type=int, default=None)
    p.add_argument("--timeout", type=float, default=None, help="seconds")
    p.add_argument("--shortcut", type=int, default=60, help="random shortcut iterations (0: none)")
    p.add_argument("--step", type=float, default=0.01, help="sampling step of the saved paths")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=run)


def _progress(stream, t0: float):
    last = [0.0]
    tty = stream.isatty()

    def show(iteration: int, nodes: int, components: int) -> None:
        now = time.perf_counter()
        if now - last[0] < (0.1 if tty else 2.0):
            return
        last[0] = now
        msg = (
            f"iteration {iteration:5d}  nodes {nodes:5d}  components {components:3d}  "
            f"{now - t0:6.2f} s"
        )
        stream.write(("\r" + msg) if tty else msg + "\n")
        stream.flush()

    return show


def run(args: argparse.Namespace) -> int:
    from marionette import REPO_ROOT
    from marionette.planning.collision import CollisionChecker
    from marionette.planning.graph_factory import graph_from_settings
    from marionette.planning.guide import guide_configuration, plan_through
    from marionette.planning.path import save_plan
    from marionette.planning.planner import (
        ManipulationRRT,
        PlanningError,
        graph_shortcut,
        random_shortcut,
    )
    from marionette.planning.problem import ProblemError, load_problem

    err = sys.stderr
    problems_dir = Path(__file__).parent / "problems"
    bundled = problems_dir / f"{args.problem}.yaml"
    if not args.problem.exists() and bundled.exists():
        args.problem = bundled
    elif not args.problem.exists():
        names = sorted(f.stem for f in problems_dir.glob("*.yaml"))
        close = difflib.get_close_matches(str(args.problem), names, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        print(
            f"marionette plan: no problem file or bundled problem {str(args.problem)!r}; "
            f"{hint}bundled: {', '.join(names)}",
            file=err,
        )
        return 2
    try:
        problem = load_problem(args.problem)
    except (ProblemError, OSError) as e:
        print(f"marionette plan: {e}", file=err)
        return 2
    if problem.q_init is None or problem.q_goal is None:
        print(f"marionette plan: {args.problem} needs 'init' and 'goal' configurations", file=err)
        return 2
    out = args.out or (REPO_ROOT / "reports" / "plans" / problem.name)
    out.mkdir(parents=True, exist_ok=True)
    settings = problem.settings.get("planner", {})
    max_it = args.max_iterations or int(settings.get("max_iterations", 5000))
    timeout = args.timeout or float(settings.get("timeout_s", 60.0))

    graph = graph_from_settings(problem)
    picture = graph.write_picture(out / "graph.png")
    print(
        f"{problem.name}: {len(graph.main_states())} states, {len(graph.states) - len(graph.main_states())} "
        f"waypoint states, {len(graph.top_edges())} transitions -> {picture}"
    )
    checker = CollisionChecker(problem)
    t0 = time.perf_counter()
    show = None if args.quiet else _progress(err, t0)
    try:
        if problem.settings.get("guide"):
            rng = np.random.default_rng(args.seed)
            waypoints = [
                guide_configuration(problem, graph, checker, entry, problem.q_init, rng)
                for entry in problem.settings["guide"]
            ]
            print(f"guided through {len(waypoints)} user waypoint(s)")
            result = plan_through(
                problem,
                graph,
                checker,
                [problem.q_init, *waypoints, problem.q_goal],
                args.seed,
                max_it,
                timeout,
                show,
            )
        else:
            planner = ManipulationRRT(problem, graph, checker, seed=args.seed)
            result = planner.solve(problem.q_init, [problem.q_goal], max_it, timeout, show)
    except PlanningError as e:
        print(f"\nmarionette plan: {e}", file=err)
        return 1
    if not args.quiet and err.isatty():
        err.write("\n")
    if not result.success:
        print(f"no plan: {result.reason}; failures: {result.statistics}", file=err)
        return 1
    print(
        f"planned in {result.time_s * 1e3:.1f} ms, {result.iterations} iterations, "
        f"{result.nodes} nodes, {len(result.paths)} paths, length {result.length:.3f}"
    )
    paths = result.paths
    if args.shortcut > 0:
        t1 = time.perf_counter()
        rng = np.random.default_rng(args.seed)
        paths = graph_shortcut(paths, graph, checker, rng, args.shortcut)
        paths = random_shortcut(paths, checker, rng, args.shortcut)
        print(
            f"shortcut: length {result.length:.3f} -> {sum(p.length for p in paths):.3f} "
            f"in {(time.perf_counter() - t1) * 1e3:.0f} ms"
        )
    json_path, npz_path = save_plan(
        out / "plan",
        graph,
        paths,
        step=args.step,
        metadata={
            "seed": args.seed,
            "planning_time_s": result.time_s,
            "iterations": result.iterations,
            "nodes": result.nodes,
            "raw_length": result.length,
        },
    )
    previous = None
    for p in paths:
        name = (p.edge.parent or p.edge).name
        if name != previous:
            print(f"  {name}")
            previous = name
    print(f"plan -> {json_path} (+ {npz_path.name})")
    return 0
