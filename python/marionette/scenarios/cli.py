"""``marionette demo [SCENARIO] [--seed S] [--trials N] [--speed X]``: the seeds' experiments as
one command, a trial writing ``reports/demo/<scenario>-<time>-seed<S>/`` (exit 0 only on
success). SCENARIO is a name (``marionette.scenarios``, or a declaration file on the search path)
or the path of a declaration file (``docs/scenarios.md``). Several trials (``--trials N``,
``--jobs K``, ``--cluster ADDRESS``) are a campaign (:mod:`marionette.campaigns`): one folder, the
trials' reports in it, one campaign report."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

INTERRUPTED_EXIT = 130  # the shell's code for Ctrl-C


def register(subparsers: argparse._SubParsersAction) -> None:
    from marionette.scenarios import DEFAULT_SCENARIO, names
    from marionette.scenarios.perturbations import PARTS, PRESETS

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
            "  marionette demo ur10-box --trials 20 --speed 0 --jobs 2   # two trials at a time\n"
            "  marionette demo ur10-box --trials 20 --speed 0 --cluster HEAD:6379  # on Ray\n"
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
        default="none",
        metavar="PRESET|KEY=VALUE,...|FILE.yaml",
        help=f"seeded perturbations per trial (scenarios/perturbations.py; presets: none, "
        f"{', '.join(PRESETS)}): displacement = object displaced <= 5 cm / 10 deg before "
        "execution; in-hand = disturbed in the hand during it (welded grasps: slipping <= 1 "
        "cm / 5 deg; friction grasps: a 2.5-5 N push) and 2 mm / 0.5 deg camera noise; "
        "joint-offsets = 7 deg shoulder / 4 deg wrist encoder offsets on both "
        f"arms; all = {', '.join(PARTS)} at once; with friction grasps, push = a 2.5-5 N bump "
        "on the held object during its first carry, slippery = its friction down to 0.25 "
        "then. Magnitudes replace or add to presets as key=value items "
        "(all,displacement_m=0.08,joint_offsets_deg.arm_right_4_joint=6) or come from a YAML "
        "file (python/marionette/schemas/perturbation.schema.json)",
    )
    p.add_argument(
        "--dry-run",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="play the generated controllers on the plan (kinematic controller) before anything "
        "moves and refuse a plan that would fail (plan-and-execute scenarios; default on)",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="controller pacing: 1 real time (default), 0 as fast as possible",
    )
    p.add_argument(
        "--split-sim",
        action="store_true",
        help="simulate the robot in marionette-sim, a separate driver process, and drive it "
        "with marionette-controller --backend driver exactly as a robot (docs/driver.md)",
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
        "--jobs",
        type=int,
        default=1,
        metavar="K",
        help="run K trials at once on this machine (each with its own processes, private LCM "
        "URL and report folder; the plan cache is shared)",
    )
    p.add_argument(
        "--cluster",
        default=None,
        metavar="ADDRESS",
        help="run each trial as a task on the Ray cluster at ADDRESS (HOST:PORT of its head, "
        "auto, or ray://HOST:PORT); every node runs this marionette (docs/scenarios.md)",
    )
    p.add_argument(
        "--campaign",
        type=Path,
        default=None,
        metavar="DIR",
        help="the campaign folder (default <out>/<scenario>-campaign-<time>): trials/, the "
        "campaign report; an existing one is resumed (its finished trials are not rerun)",
    )
    p.add_argument(
        "--retries",
        type=int,
        default=1,
        help="with --cluster: times a trial whose worker died is run again (default 1)",
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
        return 1
    from marionette.scenarios.perturbations import draw, settings_from_argument
    from marionette.schemas import DataFileError

    try:
        perturb = settings_from_argument(args.perturb)
    except DataFileError as e:  # a perturbation file: missing or invalid
        print(f"marionette demo: {e}", file=sys.stderr)
        return 1
    except ValueError as e:  # the --perturb value itself
        print(f"marionette demo: {e}", file=sys.stderr)
        return 2
    seed0 = scenario.seed if args.seed is None else args.seed
    root = args.out or (marionette.REPO_ROOT / "reports" / "demo")
    if args.trials > 1 or args.jobs != 1 or args.cluster or args.campaign:
        return _campaign(args, scenario, seed0, root, perturb)
    print(f"demo {scenario.name}: {scenario.description}")
    out = root / f"{scenario.name}-{time.strftime('%Y%m%d-%H%M%S')}-seed{seed0}"
    options = RunOptions(
        speed=args.speed,
        controller_url=args.controller_url,
        view=args.view,
        log=lambda m: print(m, flush=True),
        perturbation=None if perturb is None else draw(perturb, seed0),
        gripper_admittance=args.gripper_admittance,
        dry_run=args.dry_run,
        split_sim=args.split_sim,
    )
    try:
        report = scenario.run(seed0 if args.plan_seed is None else args.plan_seed, out, options)
    except ScenarioError as e:
        print(f"marionette demo: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"\nmarionette demo: interrupted; partial report in {out}", file=sys.stderr)
        return INTERRUPTED_EXIT
    print(f"{scenario.summary(report, seed0)} -> {out / 'report.md'}")
    return 0 if report["success"] else 1


def _campaign(args: argparse.Namespace, scenario, seed0: int, root: Path, perturb) -> int:
    """Several trials: a campaign (marionette.campaigns) on this machine or a Ray cluster;
    ``perturb``: the parsed --perturb settings (None: none)."""
    from marionette.campaigns import CampaignError, CampaignSettings, run_campaign
    from marionette.scenarios import RunOptions, ScenarioError
    from marionette.scenarios.perturbations import draw

    problem = None
    if args.jobs < 1:
        problem = f"--jobs must be >= 1, got {args.jobs}"
    elif args.retries < 0:
        problem = f"--retries must be >= 0, got {args.retries}"
    elif args.cluster and args.jobs != 1:
        problem = "--jobs is for this machine: a cluster runs as many trials as it has CPUs"
    elif args.view:
        problem = "--view shows one trial: run it alone (without --trials, --jobs, --cluster)"
    elif args.controller_url and args.split_sim:
        problem = (
            "--split-sim starts the simulator for a controller it starts: not with --controller-url"
        )
    elif args.controller_url and (args.jobs > 1 or args.cluster):
        problem = "--controller-url drives one controller: trials at once need their own"
    if problem is None:
        try:  # the options every trial takes, refused once here rather than in each trial
            scenario.check_options(
                RunOptions(
                    speed=args.speed,
                    controller_url=args.controller_url,
                    perturbation=None if perturb is None else draw(perturb, seed0),
                    gripper_admittance=args.gripper_admittance,
                    dry_run=args.dry_run,
                    split_sim=args.split_sim,
                )
            )
        except ScenarioError as e:
            problem = str(e)
    if problem is not None:
        print(f"marionette demo: {problem}", file=sys.stderr)
        return 2
    scenario_arg = args.scenario
    if Path(scenario_arg).suffix in (".yaml", ".yml") and Path(scenario_arg).exists():
        scenario_arg = str(Path(scenario_arg).resolve())  # the trials run elsewhere
    perturb_arg = args.perturb
    if Path(perturb_arg).suffix in (".yaml", ".yml") and Path(perturb_arg).exists():
        perturb_arg = str(Path(perturb_arg).resolve())
    settings = CampaignSettings(
        scenario_arg,
        seed0,
        args.trials,
        args.plan_seed,
        perturb_arg,
        args.speed,
        args.gripper_admittance,
        args.controller_url,
        args.dry_run,
        args.split_sim,
    )
    folder = args.campaign or root / f"{scenario.name}-campaign-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        report = run_campaign(
            folder, settings, scenario, args.jobs, args.cluster, args.retries, print_flush
        )
    except CampaignError as e:
        print(f"marionette demo: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            f"\nmarionette demo: interrupted; the campaign report of the finished trials is in "
            f"{folder} (run the same command with --campaign {folder} to resume)",
            file=sys.stderr,
        )
        return INTERRUPTED_EXIT
    rate, counts = report["success_rate"], report["counts"]
    lo, hi = rate["wilson"]
    print(
        f"\n{scenario.name}: {rate['successes']}/{rate['trials']} trials succeeded "
        f"({100 * lo:.0f}-{100 * hi:.0f} % at {100 * rate['confidence']:.0f} %, Wilson)"
        + (f", {counts['lost']} lost" if counts["lost"] else "")
        + f" -> {folder / 'report.md'}"
    )
    return 0 if counts["succeeded"] == len(report["trials"]) else 1


def print_flush(message: str) -> None:
    print(message, flush=True)
