"""``marionette plan <problem.yaml>``: plan, optimise, time; write the plan, draw the graph."""

from __future__ import annotations

import argparse
import difflib
import sys
import time
from pathlib import Path


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
    p.add_argument(
        "--optimize",
        type=int,
        default=60,
        metavar="N",
        help="path optimisation: N shortcut attempts per kind and round (0: keep the raw plan)",
    )
    p.add_argument(
        "--untimed",
        action="store_true",
        help="no time parameterisation in the plan file (samples by arc length only)",
    )
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
    from marionette.planning.path import save_plan
    from marionette.planning.problem import ProblemError, load_problem
    from marionette.planning.query import PlanningError
    from marionette.planning.solve import plan_problem, planner_fingerprint

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
        return 1
    try:
        problem = load_problem(args.problem)
    except (ProblemError, OSError) as e:
        print(f"marionette plan: {e}", file=err)
        return 1
    if problem.q_init is None or problem.q_goal is None:
        print(f"marionette plan: {args.problem} needs 'init' and 'goal' configurations", file=err)
        return 1
    out = args.out or (REPO_ROOT / "reports" / "plans" / problem.name)
    out.mkdir(parents=True, exist_ok=True)
    from marionette.planning.graph_factory import graph_from_settings

    graph = graph_from_settings(problem)
    picture = graph.write_picture(out / "graph.png")
    print(
        f"{problem.name}: {len(graph.main_states())} states, "
        f"{len(graph.states) - len(graph.main_states())} waypoint states, "
        f"{len(graph.top_edges())} transitions -> {picture}"
    )
    t0 = time.perf_counter()
    show = None if args.quiet else _progress(err, t0)
    try:
        solution = plan_problem(
            problem,
            seed=args.seed,
            max_iterations=args.max_iterations,
            timeout_s=args.timeout,
            optimize_iterations=args.optimize,
            progress=show,
            graph=graph,
        )
    except PlanningError as e:
        print(f"\nmarionette plan: {e}", file=err)
        return 1
    if not args.quiet and err.isatty():
        err.write("\n")
    result = solution.result
    if not result.success:
        print(f"marionette plan: no plan: {result.reason}; failures: {result.statistics}", file=err)
        return 1
    print(
        f"planned in {result.time_s * 1e3:.1f} ms, {result.iterations} iterations, "
        f"{result.nodes} nodes, {len(result.paths)} paths, length {result.length:.3f}"
    )
    paths = solution.paths
    if args.optimize > 0:
        print(
            f"optimised: length {result.length:.3f} -> {solution.length:.3f} "
            f"in {solution.optimize_s * 1e3:.0f} ms"
        )
    json_path, npz_path = save_plan(
        out / "plan",
        graph,
        paths,
        step=args.step,
        limits=None if args.untimed else solution.limits,
        metadata={
            "seed": args.seed,
            "planning_time_s": result.time_s,
            "iterations": result.iterations,
            "nodes": result.nodes,
            "raw_length": result.length,
            "optimize_iterations": args.optimize,
            "planner": planner_fingerprint(),
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
