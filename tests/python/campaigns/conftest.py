"""What every campaign test checks: the campaign report's numbers against the ones recomputed
here, independently, from the trials' own report.json files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binomtest


def _numbers(d: dict, prefix: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for k, v in d.items():
        if k == "limits" and not prefix:
            continue
        if isinstance(v, dict):
            out.update(_numbers(v, f"{prefix}{k}."))
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v):
            out[f"{prefix}{k}"] = float(v)
    return out


def check_against_trials(folder: Path, expect_trials: int) -> dict:
    """Asserts that ``folder``'s campaign report agrees with its trials' reports; returns it."""
    report = json.loads((folder / "report.json").read_text())
    trials = {}
    for f in sorted((folder / "trials").glob("seed*")):
        r = json.loads((f / "report.json").read_text())
        assert isinstance(r["success"], bool)
        trials[int(f.name.removeprefix("seed"))] = r
    k = sum(r["success"] for r in trials.values())
    n = len(trials)
    rate = report["success_rate"]
    assert (rate["successes"], rate["trials"]) == (k, n)
    assert report["counts"]["succeeded"] == k and report["counts"]["failed"] == n - k
    assert len(report["trials"]) == expect_trials
    if n:
        ci = binomtest(k, n).proportion_ci(rate["confidence"], method="wilson")
        assert rate["wilson"] == pytest.approx([ci.low, ci.high], abs=1e-12)
    values: dict[str, list[float]] = {}
    for r in trials.values():
        for path, v in _numbers(r.get("criteria") or {}).items():
            last = path.split(".")[-1]
            factor = 1e3 if last.endswith("_m") and not last.endswith("_ms") else 1.0
            values.setdefault(path, []).append(v * factor)
    assert set(values) == set(report["criteria"])
    for path, xs in values.items():
        e = report["criteria"][path]
        assert e["n"] == len(xs), path
        assert e["median"] == pytest.approx(float(np.median(xs)), rel=1e-12, abs=1e-12), path
        assert e["min"] == pytest.approx(min(xs)) and e["max"] == pytest.approx(max(xs)), path
        assert e["p90"] == pytest.approx(float(np.percentile(xs, 90)), rel=1e-12, abs=1e-12)
    for t in report["trials"]:
        if t["status"] in ("succeeded", "failed"):
            assert (folder / t["report"]).exists(), t
    md = (folder / "report.md").read_text()
    assert f"{k}/{n} succeeded" in md
    for p in report.get("plots", []):
        assert (folder / p).stat().st_size > 1000, p
    return report


@pytest.fixture
def campaign_checks():
    return check_against_trials
