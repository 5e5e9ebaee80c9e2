"""``marionette demo [SCENARIO] [--seed S] [--trials N] [--speed X]``: the seeds' experiments as
one command, each trial writing ``reports/demo/<scenario>-<time>-seed<S>/`` (exit 0 only on
success). SCENARIO is a name (``marionette.scenarios``, or a declaration file on the search path)
or the path of a declaration file (``docs/scenarios.md``)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

INTERRUPTED_EXIT = 130  # the shell's code for Ctrl-C


def register(subparsers: argparse._SubParsersAction) -> None:
    from marionette.scenarios import DEFAULT_SCENARIO, names
    from marionette.scenarios.perturbations import PARTS

    p = subparsers.add_parser(
        "demo",
        help="run a demo scenario end to end in MuJoCo and write its report",
        description="Plan (or load the cached plan), generate one controller per transition, run "
        "marionette-controller and the supervisor on a private LCM URL, record an "
        "LCM log, and write reports/demo/<scenario>-<time>/ (report.md, report.json, "
        "plots). Exit code 0 only when every trial succeeds; docs/scenarios.md describes each "
        "scenario.",
        epilog=(
            "examples:\n"
            "  marionette demo                           # the plank flip\n"
            "  marionette demo ur10-box --trials 20 --speed 0\n"
            "  marionette demo plank-flip --perturb all --trials 5\n"
            "  marionette demo my/arm-cube.yaml          # a scenario declared in a file"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "scenario",
        nargs="?",
        default=None,
        metavar="SCENARIO",
        help=f"a scenario name ({', '.join(names())}; default {DEFAULT_SCENARIO}) or the path of "
        "a scenario declaration file (.yaml)",
    )
    p.add_argument("--seed", type=int, default=None, help="planning seed (default: the scenario's)")
    p.add_argument("--trials", type=int, default=1, help="trials with seeds S, S+1, ...")
    p.add_argument(
        "--plan-seed",
        type=int,
        default=None,
        help="plan once with this seed for every trial (default: each trial plans with its "
        "own seed); the trial's seed still draws its --perturb perturbations",
    )
    p.add_argument(
        "--perturb",
        choices=("none", "all", *PARTS),
        default="none",
        help="seeded perturbations per trial (scenarios/perturbations.py): displacement = "
        "object displaced <= 5 cm / 10 deg before execution; in-hand = slipping in the hand "
        "during it (<= 1 cm / 5 deg) and 2 mm / 0.5 deg camera noise; joint-offsets = 7 deg "
        "shoulder / 4 deg wrist encoder offsets; all = the three at once",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="controller pacing: 1 real time (default), 0 as fast as possible",
    )
    p.add_argument("--out", type=Path, default=None, help="reports folder (default reports/demo)")
    p.add_argument(
        "--controller-url",
        default=None,
        metavar="URL",
        help="use the marionette-controller already running on this LCM URL (e.g. on the "
        "robot's computer, started with the scenario's --scene) instead of starting one",
    )
    p.add_argument(
        "--gripper-admittance",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="gripper_admittance tasks on the grippers with a joint (close on the handle, hold "
        "5 N, release; default: the scenario's, on for ur10-box); --no-gripper-admittance: "
        "weld-only grasps",
    )
    p.add_argument(
        "--view",
        action="store_true",
        help="serve a browser 3D view of the run (meshcat; its URL is printed; `marionette "
        "replay LOG --view` plays a recorded run in it)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import marionette
    from marionette.scenarios import DEFAULT_SCENARIO, RunOptions, ScenarioError, find, names

    if args.scenario is None:
        print(
            f"marionette demo: no scenario given, running {DEFAULT_SCENARIO!r} "
            f"(choose among {', '.join(names())})"
        )
        args.scenario = DEFAULT_SCENARIO
    if args.trials < 1:
        print("marionette demo: --trials must be >= 1", file=sys.stderr)
        return 2
    if args.speed < 0:
        print("marionette demo: --speed must be >= 0", file=sys.stderr)
        return 2
    try:
        scenario = find(args.scenario)
    except ScenarioError as e:
        print(f"marionette demo: {e}", file=sys.stderr)
        return 2
    seed0 = scenario.seed if args.seed is None else args.seed
    root = args.out or (marionette.REPO_ROOT / "reports" / "demo")
    print(f"demo {scenario.name}: {scenario.description}")
    rows = []
    for k in range(args.trials):
        seed = seed0 + k
        out = root / f"{scenario.name}-{time.strftime('%Y%m%d-%H%M%S')}-seed{seed}"
        perturbation = None
        if args.perturb != "none":
            from marionette.scenarios.perturbations import PRESETS, draw

            perturbation = draw(PRESETS[args.perturb], seed)
        options = RunOptions(
            speed=args.speed,
            controller_url=args.controller_url,
            view=args.view,
            log=lambda m: print(m, flush=True),
            perturbation=perturbation,
            gripper_admittance=args.gripper_admittance,
        )
        try:
            report = scenario.run(seed if args.plan_seed is None else args.plan_seed, out, options)
        except ScenarioError as e:
            print(f"marionette demo: {e}", file=sys.stderr)
            rows.append((seed, False, str(e).splitlines()[0], out, None))
            continue
        except KeyboardInterrupt:
            print(f"\nmarionette demo: interrupted; partial report in {out}", file=sys.stderr)
            return INTERRUPTED_EXIT
        reason = "" if report["success"] else scenario.failure_reason(report)
        rows.append((seed, report["success"], reason, out, report.get("criteria")))
        print(f"{scenario.summary(report, seed)} -> {out / 'report.md'}")
    if args.trials > 1:
        ok = sum(r[1] for r in rows)
        print(
            f"\n{scenario.name}: {ok}/{len(rows)} trials succeeded ({100.0 * ok / len(rows):.0f} %)"
        )
        print("| seed | success | error mm | error ° | failure reason |\n|---|---|---|---|---|")
        for seed, success, reason, _, c in rows:
            placed = c is not None and "object_position_error_m" in c  # walking: no object goal
            mm = f"{c['object_position_error_m'] * 1e3:.1f}" if placed else "-"
            deg = f"{c['object_angle_error_deg']:.2f}" if placed else "-"
            print(f"| {seed} | {success} | {mm} | {deg} | {reason} |")
        summary = root / f"{scenario.name}-trials-{time.strftime('%Y%m%d-%H%M%S')}.json"
        summary.write_text(
            json.dumps(
                {
                    "scenario": scenario.name,
                    "perturb": args.perturb,
                    "speed": args.speed,
                    "succeeded": ok,
                    "trials": len(rows),
                    "rows": [
                        {
                            "seed": seed,
                            "success": success,
                            "failure_reason": reason,
                            "report": str(o),
                            "object_position_error_m": c and c.get("object_position_error_m"),
                            "object_angle_error_deg": c and c.get("object_angle_error_deg"),
                        }
                        for seed, success, reason, o, c in rows
                    ],
                },
                indent=1,
            )
        )
        print(f"trials: {summary}")
    return 0 if all(r[1] for r in rows) else 1
