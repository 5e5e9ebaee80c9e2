"""The report pieces every scenario shares: report.json (values NumPy or not), report.md with its
common sections, plots that never hide a verdict, the controller's summary, and the partial report
of a trial that failed or was interrupted."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def jsonable(x: Any) -> Any:
    """``json.dumps``' ``default``: NumPy scalars and arrays as numbers and lists, else ``str``."""
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def write_json(path: Path, report: dict[str, Any]) -> None:
    path.write_text(json.dumps(report, indent=1, default=jsonable))


def write_report_files(
    out_dir: Path,
    report: dict[str, Any],
    plots: Callable[[], list[Path]],
    markdown: Callable[[dict[str, Any]], str],
) -> None:
    """report.json and report.md; the plots' names in ``report["plots"]``. A failing plot is
    recorded as ``plot_error``: a plot must never hide the run's verdict."""
    paths: list[Path] = []
    try:
        paths = plots()
    except Exception as e:
        report["plot_error"] = repr(e)
    report["plots"] = [p.name for p in paths]
    write_json(out_dir / "report.json", report)
    (out_dir / "report.md").write_text(markdown(report))


def write_partial_report(out_dir: Path, report: dict[str, Any], reason: str) -> None:
    """The report of a trial that stopped before its verdict (an error, Ctrl-C): what it had
    measured, ``success`` false and ``stopped`` = ``reason``."""
    report["success"] = False
    report["stopped"] = reason
    write_json(out_dir / "report.json", report)
    lines = [
        f"# Demo `{report['scenario']}` — STOPPED (partial report)",
        "",
        report.get("description", ""),
        "",
        f"seed {report['seed']}, {speed_text(report['speed'])}: the trial stopped before its "
        f"verdict: {reason}",
        "",
        "`report.json` holds what was measured until then; `run.lcmlog` and `logs/` (process "
        "outputs) what was recorded.",
    ]
    if "timings" in report:
        lines += ["", *timings_lines(report["timings"])]
    (out_dir / "report.md").write_text("\n".join(lines) + "\n")


def controller_summary(status: Any) -> dict[str, Any]:
    """The controller's state at the end of a run (CONTROLLER_STATUS): ``report["controller"]``."""
    return {
        "mode": status.mode,
        "mode_reason": status.mode_reason,
        "realtime_factor": status.realtime_factor,
        "deadline_misses": status.deadline_misses,
        "num_rejected": status.num_rejected,
        "num_switches": status.num_switches,
        "num_refused_switches": status.num_refused_switches,
        "last_rejection": status.last_rejection,
    }


def heartbeat_summary(heartbeat: Any) -> dict[str, Any]:
    """The supervisor's heartbeat at the end of a run (marionette._wire.Heartbeat):
    ``report["heartbeat"]``. ``longest_python_stall_s``: the longest time the trial's Python was
    kept from running — what a heartbeat sent from Python would have been silent for;
    ``longest_beat_gap_s``: the longest silence the heartbeat itself left (the machine's load)."""
    return {
        "beats": heartbeat.beats,
        "withheld": heartbeat.withheld,
        "longest_python_stall_s": heartbeat.longest_feed_gap_s,
        "longest_beat_gap_s": heartbeat.longest_beat_gap_s,
    }


def speed_text(speed: float) -> str:
    """How fast the trial's controller ran, for its report.md (report.json: ``speed``)."""
    if speed == 0:
        return "controller speed 0 (unpaced: as fast as the CPU allows, simulated time)"
    return f"controller speed {speed:g} (× real time)"


def title(report: dict[str, Any]) -> str:
    return f"# Demo `{report['scenario']}` — {'SUCCESS' if report['success'] else 'FAILURE'}"


def timings_lines(timings: dict[str, float]) -> list[str]:
    return ["## Timings", "", "| phase | s |", "|---|---|"] + [
        f"| {k} | {v:.2f} |" for k, v in timings.items()
    ]


def controller_and_plots_lines(report: dict[str, Any]) -> list[str]:
    """The report.md sections ``## Controller`` (its summary) and ``## Plots``."""
    return [
        "",
        "## Controller",
        "",
        ", ".join(f"{k}: {v}" for k, v in report.get("controller", {}).items()),
        "",
        *(
            [
                "supervisor heartbeat (sent from C++, fed from Python): "
                + ", ".join(f"{k}: {v}" for k, v in report["heartbeat"].items()),
                "",
            ]
            if "heartbeat" in report
            else []
        ),
        "## Plots",
        "",
    ] + [f"![{p}]({p})" for p in report.get("plots", [])]


def save_figure(fig: Any, path: Path) -> Path:
    """A matplotlib figure written to ``path`` (tight layout, 110 dpi) and closed."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
