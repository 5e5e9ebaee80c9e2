"""The campaign report: ``report.json``, ``report.md`` and PNGs in the campaign folder, from the
trials' own reports.

* the success rate over the trials with a verdict, with its Wilson interval (:mod:`.stats`);
* the failure reasons grouped (numbers masked: "stale for 201 ms" and "stale for 230 ms" are one
  reason) with their trials;
* the distribution of every number a trial's ``criteria`` carries (nested entries as ``a.b``),
  and of every number per hole of a ``holes`` list, in the unit its name ends with (``_m`` shown
  in mm, ``_deg``, ``_n``, ``_s``, ``_ms``, ``_hz``; a whole number without unit is a count), and
  how many trials passed each yes/no criterion;
* the slowest trials and the worst ones (the failures, then the extreme trial of every error,
  displacement, drop or distance (the highest) and every margin or clearance (the lowest)),
  linked to their own reports;
* each trial: verdict, reason, wall time, host, attempts, its seed's draw (perturbation).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from marionette.campaigns.stats import describe, wilson_interval
from marionette.scenarios.report import save_figure, write_json

CONFIDENCE = 0.95
# Name suffix -> (unit shown, factor from the report's value); "_m" last: "_ms" ends otherwise.
UNITS: tuple[tuple[str, str, float], ...] = (
    ("_deg", "deg", 1.0),
    ("_ms", "ms", 1.0),
    ("_hz", "Hz", 1.0),
    ("_n", "N", 1.0),
    ("_s", "s", 1.0),
    ("_m", "mm", 1e3),
)
HIGH_IS_WORSE = ("error", "displacement", "drop", "distance", "moved")
LOW_IS_WORSE = ("margin", "clearance")


@dataclass
class TrialRow:
    """One trial of the campaign as the report sees it. ``status``: succeeded, failed (a
    verdict), lost (its process or worker died without a report) or pending (not run yet);
    ``folder``: its report folder relative to the campaign folder; ``run``: how it ran (host,
    wall_s, attempts, exit_code)."""

    seed: int
    status: str
    reason: str = ""
    folder: str | None = None
    report: dict[str, Any] | None = None
    run: dict[str, Any] = field(default_factory=dict)
    draw: dict[str, Any] = field(default_factory=dict)


def unit_of(path: str, value: float) -> tuple[str, float]:
    """(unit shown, factor) of the number at ``path`` (``a.b.c``): from the last name with a unit
    suffix; a whole number without one is a count."""
    for part in reversed(path.split(".")):
        for suffix, unit, factor in UNITS:
            if part.endswith(suffix):
                return unit, factor
    return ("count", 1.0) if float(value).is_integer() else ("no unit", 1.0)


def label(path: str, unit: str) -> str:
    """An axis label: the name without its unit suffix, the unit shown in brackets."""
    head, _, last = path.rpartition(".")
    for suffix, _, _ in UNITS:
        if last.endswith(suffix):
            last = last[: -len(suffix)]
            break
    return f"{head + '.' if head else ''}{last} [{unit}]"


def worse_when(path: str) -> str | None:
    """ "high" when a larger value is worse (errors, displacements, drops, distances), "low" for
    margins and clearances, None for the rest (counts, rates)."""
    name = path.split(".")[-1]
    if any(w in name for w in LOW_IS_WORSE):
        return "low"
    if any(w in name for w in HIGH_IS_WORSE):
        return "high"
    return None


def numbers(entries: dict[str, Any], prefix: str = "") -> Iterator[tuple[str, float]]:
    """(``a.b``, value) of every finite number in ``entries`` and its nested dictionaries
    (booleans, lists and ``limits`` left out)."""
    for key, value in entries.items():
        path = f"{prefix}{key}"
        if key == "limits" and not prefix:
            continue
        if isinstance(value, dict):
            yield from numbers(value, path + ".")
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            if math.isfinite(value):
                yield path, float(value)


def flags(entries: dict[str, Any]) -> Iterator[tuple[str, bool]]:
    """(name, value) of the yes/no criteria."""
    for key, value in entries.items():
        if isinstance(value, bool):
            yield key, value


def reason_group(reason: str) -> str:
    """A failure reason with its numbers masked as #."""
    return re.sub(r"[-+]?\d+(\.\d+)?(e[-+]?\d+)?", "#", reason)


def aggregate(rows: list[TrialRow], campaign: dict[str, Any]) -> dict[str, Any]:
    """The campaign report (report.json) of ``rows``; ``campaign``: its settings and timing."""
    judged = [r for r in rows if r.status in ("succeeded", "failed")]
    k = sum(r.status == "succeeded" for r in judged)
    lo, hi = wilson_interval(k, len(judged), CONFIDENCE)
    out: dict[str, Any] = {
        "campaign": campaign,
        "counts": {
            s: sum(r.status == s for r in rows) for s in ("succeeded", "failed", "lost", "pending")
        },
        "success_rate": {
            "successes": k,
            "trials": len(judged),
            "rate": k / len(judged) if judged else None,
            "confidence": CONFIDENCE,
            "wilson": [lo, hi],
        },
    }
    groups: dict[str, dict[str, Any]] = {}
    for r in rows:
        if r.status in ("failed", "lost"):
            key = ("lost: " if r.status == "lost" else "") + reason_group(r.reason)
            g = groups.setdefault(key, {"reason": key, "example": r.reason, "seeds": []})
            g["seeds"].append(r.seed)
    out["failure_groups"] = sorted(groups.values(), key=lambda g: (-len(g["seeds"]), g["reason"]))
    out["criteria"] = _distributions(
        [(r.seed, dict(numbers(r.report.get("criteria") or {}))) for r in judged if r.report]
    )
    hole_values: list[tuple[int, dict[str, float]]] = []
    for r in judged:
        for hole in (r.report or {}).get("holes") or []:
            hole_values.append(
                (r.seed, {p: v for p, v in numbers(hole) if unit_of(p, v)[0] not in ("count",)})
            )
    out["holes"] = _distributions(hole_values)
    passed: dict[str, list[int]] = {}
    for r in judged:
        for key, value in flags((r.report or {}).get("criteria") or {}):
            passed.setdefault(key, [0, 0])
            passed[key][0] += int(value)
            passed[key][1] += 1
    out["criteria_passed"] = {k: {"passed": p, "of": n} for k, (p, n) in sorted(passed.items())}
    walls = [(r.seed, r.run["wall_s"]) for r in rows if r.run.get("wall_s")]
    out["trial_wall_s"] = describe([w for _, w in walls])
    out["slowest"] = [s for s, _ in sorted(walls, key=lambda sw: -sw[1])[:3]]
    out["worst"] = _worst(rows, out["criteria"])
    out["trials"] = [
        {
            "seed": r.seed,
            "status": r.status,
            "reason": r.reason,
            "report": r.folder and f"{r.folder}/report.md",
            "speed": (r.report or {}).get("speed"),
            "draw": r.draw,
            **{k: r.run.get(k) for k in ("host", "wall_s", "attempts", "exit_code")},
        }
        for r in rows
    ]
    return out


def _distributions(samples: list[tuple[int, dict[str, float]]]) -> dict[str, Any]:
    """path -> unit, factor, summary (in the unit shown) and the (seed, value as reported) of
    every sample that has it."""
    out: dict[str, Any] = {}
    for seed, values in samples:
        for path, v in values.items():
            entry = out.get(path)
            if entry is None:
                unit, factor = unit_of(path, v)
                entry = out[path] = {"unit": unit, "factor": factor, "values": []}
            entry["values"].append([seed, v])
    for entry in out.values():
        entry.update(describe([v * entry["factor"] for _, v in entry["values"]]))
    return dict(sorted(out.items()))


def _worst(rows: list[TrialRow], criteria: dict[str, Any]) -> list[dict[str, Any]]:
    worst = [{"seed": r.seed, "why": r.status} for r in rows if r.status in ("failed", "lost")]
    for path, entry in criteria.items():
        direction = worse_when(path)
        if direction is None or not entry["values"]:
            continue
        pick = max if direction == "high" else min
        seed, v = pick(entry["values"], key=lambda sv: sv[1])
        worst.append(
            {
                "seed": seed,
                "why": f"{'largest' if direction == 'high' else 'smallest'} {path}",
                "value": v * entry["factor"],
                "unit": entry["unit"],
            }
        )
    return worst


def write_campaign_report(folder: Path, report: dict[str, Any], plots: bool) -> None:
    """report.json and report.md in ``folder``; the PNGs too when ``plots`` (a failing plot is
    recorded as ``plot_error``, never hides the numbers)."""
    if plots:
        try:
            report["plots"] = [p.name for p in _plots(folder, report)]
        except Exception as e:
            report["plot_error"] = repr(e)
    write_json(folder / "report.json", report)
    (folder / "report.md").write_text(markdown(report))


def _percent(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def markdown(r: dict[str, Any]) -> str:
    c, rate, counts = r["campaign"], r["success_rate"], r["counts"]
    trials = {t["seed"]: t for t in r["trials"]}

    def link(seed: int) -> str:
        t = trials[seed]
        return f"[{seed}]({t['report']})" if t["report"] else str(seed)

    speed = c["speed"]
    lines = [
        f"# Campaign `{c['scenario']}` — {rate['successes']}/{rate['trials']} succeeded "
        f"({_percent(rate['rate'])}; {100 * rate['confidence']:.0f} % Wilson interval "
        f"{_percent(rate['wilson'][0])}–{_percent(rate['wilson'][1])})",
        "",
        f"- trials: seeds {c['first_seed']}–{c['first_seed'] + c['trials'] - 1}"
        + (f", all planned with seed {c['plan_seed']}" if c.get("plan_seed") is not None else "")
        + f"; perturbation `{c['perturb']}`",
        f"- controller speed {speed:g}"
        + (" (unpaced: as fast as the CPU allows)" if speed == 0 else " × real time"),
        f"- ran on: {c.get('engine', '-')}; campaign wall time {c.get('wall_s', 0.0):.0f} s"
        f" (this session), trial wall time median {_fmt(r['trial_wall_s'].get('median', 0))} s",
        f"- {counts['succeeded']} succeeded, {counts['failed']} failed, {counts['lost']} lost "
        f"(no report: process or worker died), {counts['pending']} not run yet. The rate counts "
        "the trials with a verdict.",
        "",
        "## Failures",
        "",
    ]
    if r["failure_groups"]:
        lines += ["| reason (numbers as #) | trials | seeds |", "|---|---|---|"]
        lines += [
            f"| {g['reason']} | {len(g['seeds'])} | {', '.join(link(s) for s in g['seeds'])} |"
            for g in r["failure_groups"]
        ]
    else:
        lines.append("none")
    lines += ["", "## Criteria over the trials", ""]
    lines += [
        "| criterion | unit | trials | min | median | p90 | max |",
        "|---|---|---|---|---|---|---|",
    ]
    for family, entries in (("", r["criteria"]), ("per hole: ", r["holes"])):
        lines += [
            f"| {family}{p} | {e['unit']} | {e['n']} | {_fmt(e['min'])} | {_fmt(e['median'])} | "
            f"{_fmt(e['p90'])} | {_fmt(e['max'])} |"
            for p, e in entries.items()
        ]
    if r["criteria_passed"]:
        lines += ["", "| yes/no criterion | passed |", "|---|---|"]
        lines += [f"| {k} | {v['passed']}/{v['of']} |" for k, v in r["criteria_passed"].items()]
    lines += ["", "## Slowest and worst trials", ""]
    lines.append(
        "slowest: "
        + (", ".join(f"{link(s)} ({trials[s]['wall_s']:.0f} s)" for s in r["slowest"]) or "-")
    )
    lines.append("")
    for w in r["worst"]:
        value = f" = {_fmt(w['value'])} {w['unit']}" if "value" in w else ""
        lines.append(f"- {link(w['seed'])}: {w['why']}{value}")
    lines += ["", "## Trials", ""]
    lines += [
        "| seed | status | wall s | host | attempts | draw | reason |",
        "|---|---|---|---|---|---|---|",
    ]
    for t in r["trials"]:
        wall = f"{t['wall_s']:.0f}" if t.get("wall_s") else "-"
        lines.append(
            f"| {link(t['seed'])} | {t['status']} | {wall} | {t.get('host') or '-'} | "
            f"{t.get('attempts') or '-'} | {_draw_text(t['draw'])} | {t['reason']} |"
        )
    lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in r.get("plots", [])]
    return "\n".join(lines) + "\n"


def _draw_text(draw: dict[str, Any]) -> str:
    """A trial's draw on one line: numbers rounded, nested entries flattened."""
    if not draw:
        return "-"

    def short(v: Any) -> str:
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k}: {short(x)}" for k, x in v.items()) + "}"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(short(x) for x in v) + "]"
        if isinstance(v, float):
            return f"{v:.3g}"
        return str(v)

    return "; ".join(f"{k}: {short(v)}" for k, v in draw.items()).replace("|", "/")


def _plots(folder: Path, r: dict[str, Any]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    status = {t["seed"]: t["status"] for t in r["trials"]}
    out = []
    varying = {p: e for p, e in r["criteria"].items() if e["n"] > 0 and e["max"] > e["min"]}
    if varying:
        ncols = min(3, len(varying))
        nrows = math.ceil(len(varying) / ncols)
        fig, axes = plt.subplots(nrows, ncols, figsize=(4.6 * ncols, 3.2 * nrows), squeeze=False)
        for ax, (path, e) in zip(axes.flat, varying.items()):
            ok = [v * e["factor"] for s, v in e["values"] if status.get(s) == "succeeded"]
            bad = [v * e["factor"] for s, v in e["values"] if status.get(s) != "succeeded"]
            bins = np.linspace(e["min"], e["max"], min(20, max(5, e["n"] // 2)) + 1)
            ax.hist(
                [ok, bad],
                bins=bins,
                stacked=True,
                color=["tab:blue", "tab:red"],
                label=["succeeded", "failed"],
            )
            ax.set_xlabel(label(path, e["unit"]))
            ax.set_ylabel("trials")
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        for ax in list(axes.flat)[len(varying) :]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=8)
        fig.suptitle("criteria over the trials (blue succeeded, red failed)")
        out.append(save_figure(fig, folder / "criteria.png"))
    holes = {p: e for p, e in r["holes"].items() if e["n"] > 0}
    if holes:
        names = sorted(holes)[:4]
        fig, axes = plt.subplots(1, len(names), figsize=(4.6 * len(names), 3.4), squeeze=False)
        for ax, path in zip(axes.flat, names):
            e = holes[path]
            ax.boxplot([v * e["factor"] for _, v in e["values"]])
            ax.set_xticks([1], [f"all holes of all trials (n = {e['n']})"])
            ax.set_ylabel(label(path, e["unit"]))
        fig.suptitle("per-hole errors")
        out.append(save_figure(fig, folder / "holes.png"))
    walls = [(t["seed"], t["wall_s"], t["status"]) for t in r["trials"] if t.get("wall_s")]
    if walls:
        fig, ax = plt.subplots(figsize=(max(6.0, 0.3 * len(walls)), 3.4))
        colour = {"succeeded": "tab:blue", "failed": "tab:red", "lost": "tab:gray"}
        ax.bar(
            [str(s) for s, _, _ in walls],
            [w for _, w, _ in walls],
            color=[colour.get(st, "tab:gray") for _, _, st in walls],
        )
        ax.set_xlabel("trial seed")
        ax.set_ylabel("trial wall time [s]")
        ax.tick_params(axis="x", labelrotation=90, labelsize=7)
        rate = r["success_rate"]
        ax.set_title(
            f"{rate['successes']}/{rate['trials']} succeeded, {100 * rate['confidence']:.0f} % "
            f"Wilson interval {_percent(rate['wilson'][0])}–{_percent(rate['wilson'][1])}"
        )
        out.append(save_figure(fig, folder / "trials.png"))
    return out
