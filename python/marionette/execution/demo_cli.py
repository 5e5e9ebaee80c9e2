"""``marionette demo [SCENARIO] [--seed S] [--trials N] [--speed X]``: the seeds' experiments as
one command, each trial writing ``reports/demo/<scenario>-<time>/`` (exit 0 only on success)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _step_over(*args, **kwargs):
    from marionette.execution.step_over import run_step_over

    return run_step_over(*args, **kwargs)


def _drill(*args, **kwargs):
    from marionette.execution.drill import run_drill

    return run_drill(*args, **kwargs)


def _deburr(*args, **kwargs):
    from marionette.execution.deburr import run_deburr

    return run_deburr(*args, **kwargs)


def register(subparsers: argparse._SubParsersAction) -> None:
    import marionette
    from marionette.execution.demo import DEFAULT_SCENARIO, SCENARIOS, Scenario

    SCENARIOS.setdefault(
        "step-over",
        Scenario(
            "step-over",
            "",
            marionette.MODELS_DIR / "scenes" / "talos_walk.xml",
            0,
            "bar",
            0.0,
            description="TALOS walks over a bar to a goal zone while the bar's perceived pose moves; "
            "the footstep process replans (thesis 001 ch. 5, Algorithm 3)",
            runner=_step_over,
        ),
    )
    SCENARIOS.setdefault(
        "drill",
        Scenario(
            "drill",
            "",
            marionette.MODELS_DIR / "scenes" / "ur10_drill.xml",
            0,
            "part",
            0.0,
            description="UR10 aligns its drill on the reference holes R1, R2 of the displaced aircraft "
            "part, then interpolates the other holes (thesis 000 §6.3; 0.2 mm / 0.5°)",
            runner=_drill,
        ),
    )
    SCENARIOS.setdefault(
        "deburr",
        Scenario(
            "deburr",
            "",
            marionette.MODELS_DIR / "scenes" / "tiago_deburr.xml",
            0,
            "part",
            0.0,
            description="TIAGo deburrs the holes of the displaced aircraft part with a tool held off its "
            "nominal pose, holes ordered by a TSP solver, each reached under visual servoing "
            "(thesis 000 §5.3.3; tool axis within 1 mm / 1°)",
            runner=_deburr,
        ),
    )

    p = subparsers.add_parser(
        "demo",
        help="run a demo scenario end to end in MuJoCo and write its report",
        description="Plan (or load the cached plan), generate one controller per transition, run "
        "marionette-controller and the supervisor on a private LCM URL, record an "
        "LCM log, and write reports/demo/<scenario>-<time>/ (report.md, report.json, "
        "plots). Exit code 0 only when every trial succeeds.",
    )
    p.add_argument(
        "scenario",
        nargs="?",
        default=None,
        choices=sorted(SCENARIOS),
        help=f"(default {DEFAULT_SCENARIO})",
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
        choices=("none", "issue10", "in-hand", "displacement", "joint-offsets"),
        default="none",
        help="seeded perturbations per trial (execution/perturbations.py PRESETS): issue10 = "
        "object displaced <= 5 cm / 10 deg before execution and slipping in the hand during "
        "it, 7 deg shoulder / 4 deg wrist encoder offsets, 2 mm / 0.5 deg camera noise; the "
        "others are its parts (in-hand = slip + camera noise)",
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
    from marionette.execution.demo import SCENARIOS, DemoError, run_demo

    if args.scenario is None:
        from marionette.execution.demo import DEFAULT_SCENARIO

        print(
            f"marionette demo: no scenario given, running {DEFAULT_SCENARIO!r} "
            f"(choose among {', '.join(sorted(SCENARIOS))})"
        )
        args.scenario = DEFAULT_SCENARIO
    scenario = SCENARIOS[args.scenario]
    if args.trials < 1:
        print("marionette demo: --trials must be >= 1", file=sys.stderr)
        return 2
    if args.speed < 0:
        print("marionette demo: --speed must be >= 0", file=sys.stderr)
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
            from marionette.execution.perturbations import PRESETS, draw

            perturbation = draw(PRESETS[args.perturb], seed)
        try:
            report = run_demo(
                scenario,
                seed if args.plan_seed is None else args.plan_seed,
                out,
                speed=args.speed,
                controller_url=args.controller_url,
                log=lambda m: print(m, flush=True),
                perturbation=perturbation,
                view=args.view,
                **(
                    {}
                    if args.gripper_admittance is None or scenario.runner is not None
                    else {"gripper_admittance": args.gripper_admittance}
                ),
            )
        except DemoError as e:
            print(f"marionette demo: {e}", file=sys.stderr)
            rows.append((seed, False, str(e).splitlines()[0], out, None))
            continue
        reason = "" if report["success"] else _failure_reason(report)
        rows.append((seed, report["success"], reason, out, report.get("criteria")))
        if "summary" in report:  # a demo with its own criteria (grasp-walk)
            print(f"{report['summary']} -> {out / 'report.md'}")
            continue
        c = report["criteria"]
        print(
            f"{'SUCCESS' if report['success'] else 'FAILURE'} (seed {seed}): {scenario.object_name} "
            f"{c['object_position_error_m'] * 1e3:.1f} mm / {c['object_angle_error_deg']:.2f}° from "
            f"the goal"
            + (
                f", feet moved {c['feet_max_displacement_m'] * 1e3:.2f} mm"
                if "feet_max_displacement_m" in c
                else ""
            )
            + f" -> {out / 'report.md'}"
        )
    if args.trials > 1:
        ok = sum(r[1] for r in rows)
        print(
            f"\n{scenario.name}: {ok}/{len(rows)} trials succeeded ({100.0 * ok / len(rows):.0f} %)"
        )
        print("| seed | success | error mm | error ° | failure reason |\n|---|---|---|---|---|")
        for seed, success, reason, _, c in rows:
            placed = (
                c is not None and "object_position_error_m" in c
            )  # runner demos: no object goal
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


def _failure_reason(report) -> str:
    if "summary" in report:
        return report["summary"]
    c = report["criteria"]
    if not c["fsm_done"]:
        return f"supervisor: {report['supervisor']['reason']}"
    reasons = []
    if not c["object_within_tolerance"]:
        reasons.append(
            f"object {c['object_position_error_m'] * 1e3:.1f} mm / "
            f"{c['object_angle_error_deg']:.1f}° from the goal"
        )
    if c.get("feet_never_moved") is False:
        reasons.append(f"feet moved {c['feet_max_displacement_m'] * 1e3:.1f} mm")
    if c.get("no_fall") is False:
        reasons.append("fell")
    return "; ".join(reasons)
