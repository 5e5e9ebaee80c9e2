"""``marionette replay LOG --controller|--supervisor|--view``: re-run a recorded run offline.

``--supervisor`` re-takes the supervisor FSM's decisions from the recorded inputs (the
supervisor's journal beside the log when there is one:
:mod:`marionette.execution.decision_replay`); ``--view`` plays the log in the browser viewer and
re-plots the report (:mod:`marionette.viewer.replay`). ``--controller``:

The controller journals which input messages its loop consumed at which tick; with the LCM log
of the run, ``marionette-controller --replay`` rebuilds the same controller, runs the same loop
on a simulated clock with those inputs at those ticks, and compares every recorded
ROBOT_COMMAND. This command wraps it: it prints the verdict (and the first diverging tick and
signal on a mismatch) and exits 0 only when the replay reproduces the recording.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import marionette

# The controller's own journal of a run (marionette-controller --journal), beside the run's LCM
# log in a demo's report folder: every input it took, even those the network logger dropped.
JOURNAL_NAME = "controller-journal.lcmlog"


def controller_binary() -> Path:
    return marionette.BUILD_DIR / "marionette-controller"


def replay_controller(
    log: Path, tolerance: float = 1e-9, scene: str | None = None, max_ticks: int | None = None
) -> dict:
    """Replays ``log`` and returns the verdict as a dict (see
    cpp/include/marionette/controller/replay.h): ok, ticks, inputs, commands_compared,
    max_difference, first_divergence_tick, first_divergence, journal_mismatches, problems, plus
    ``output`` (what the replay printed)."""
    if not Path(log).is_file():
        raise FileNotFoundError(f"no LCM log at {log}")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "replay.json"
        argv = [
            str(controller_binary()),
            "--replay",
            str(log),
            "--tolerance",
            repr(tolerance),
            "--json",
            str(out),
        ]
        if scene:
            argv += ["--scene", scene]
        if max_ticks is not None:
            argv += ["--max-ticks", str(max_ticks)]
        journal = Path(log).parent / JOURNAL_NAME
        if journal.is_file():
            argv += ["--journal", str(journal)]
        proc = subprocess.run(argv, capture_output=True, text=True)
        if proc.returncode == 2 or not out.exists():
            raise RuntimeError(
                f"replay of {log} failed: {proc.stderr.strip() or proc.stdout.strip()}"
            )
        result = json.loads(out.read_text())
    result["output"] = proc.stdout
    return result


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="re-run a recorded run offline and check it reproduces the recording",
        epilog=(
            "examples:\n"
            "  marionette replay reports/demo/<run>/run.lcmlog --controller\n"
            "  marionette replay reports/demo/<run>/run.lcmlog --supervisor\n"
            "  marionette replay reports/demo/<run>/run.lcmlog --view"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "log",
        type=Path,
        help="LCM log of the run (e.g. a demo's report folder's run.lcmlog)",
    )
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument(
        "--controller",
        action="store_true",
        help="replay the C++ controller's graph from its journal",
    )
    mode.add_argument(
        "--supervisor",
        action="store_true",
        help="re-take the supervisor's decisions from the recorded statuses and events and "
        "compare them with the recorded SUPERVISOR_DECISION messages",
    )
    mode.add_argument(
        "--view",
        action="store_true",
        help="play the log in the browser viewer (its URL is printed) and re-plot the report",
    )
    p.add_argument("--speed", type=float, default=1.0, help="--view: playback speed (0 = unpaced)")
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="--view: folder of the re-plotted report (default: <log folder>/replay)",
    )
    p.add_argument(
        "--no-hold", action="store_true", help="--view: exit once played instead of serving on"
    )
    p.add_argument(
        "--tolerance", type=float, default=1e-9, help="largest accepted command difference"
    )
    p.add_argument("--scene", default=None, help="MJCF scene to use instead of the recorded path")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if args.supervisor:
        return _run_supervisor(args)
    if args.view:
        return _run_view(args)
    try:
        result = replay_controller(args.log, args.tolerance, args.scene)
    except (FileNotFoundError, RuntimeError) as e:
        print(f"marionette replay: {e}", file=sys.stderr)
        return 1
    sys.stdout.write(result["output"])
    return 0 if result["ok"] else 1


def _run_supervisor(args: argparse.Namespace) -> int:
    from marionette.execution.decision_replay import (
        DecisionLogError,
        decision_record,
        format_verdict,
        replay_supervisor,
    )

    record = decision_record(args.log)
    try:
        result = replay_supervisor(record)
    except (FileNotFoundError, DecisionLogError) as e:
        print(f"marionette replay: {e}", file=sys.stderr)
        return 1
    sys.stdout.write(format_verdict(record, result))
    return 0 if result.ok else 1


def _run_view(args: argparse.Namespace) -> int:
    from marionette.viewer.replay import ReplayError, serve_replay
    from marionette.viewer.scene import ViewerError

    if args.speed < 0:
        print("marionette replay: --speed must be >= 0", file=sys.stderr)
        return 2
    try:
        return serve_replay(
            args.log,
            args.speed,
            args.scene and Path(args.scene),
            args.out or Path(args.log).parent / "replay",
            not args.no_hold,
        )
    except (FileNotFoundError, ReplayError, ViewerError) as e:
        print(f"marionette replay: {e}", file=sys.stderr)
        return 1
