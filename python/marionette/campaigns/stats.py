"""Statistics of a campaign: the success rate's confidence interval and the summary of a
criterion's values over the trials."""

from __future__ import annotations

import math
from collections.abc import Sequence
from statistics import NormalDist

import numpy as np


def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a success rate: the rates p whose score test does not reject
    ``successes`` out of ``trials`` at ``confidence``, i.e. the p with
    (p̂ − p)² ≤ z² p (1 − p) / n, p̂ = k / n, z the normal quantile of (1 + confidence) / 2:

        centre = (p̂ + z² / 2n) / (1 + z² / n)
        half   = z / (1 + z² / n) · sqrt(p̂ (1 − p̂) / n + z² / 4n²)

    Unlike p̂ ± z sqrt(p̂ (1 − p̂) / n) it stays inside [0, 1] and is not empty at 0 or n
    successes (20/20 gives [0.839, 1] at 95 %). ``(0, 1)`` for no trial."""
    if not 0 <= successes <= trials:
        raise ValueError(f"need 0 <= successes <= trials, got {successes} of {trials}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    if trials == 0:
        return 0.0, 1.0
    n, p = trials, successes / trials
    z = NormalDist().inv_cdf(0.5 + confidence / 2.0)
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z / denominator * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def describe(values: Sequence[float]) -> dict[str, float | int]:
    """n, min, median, 90th percentile (linear interpolation), max and mean of ``values``."""
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        return {"n": 0}
    return {
        "n": int(x.size),
        "min": float(x.min()),
        "median": float(np.median(x)),
        "p90": float(np.percentile(x, 90)),
        "max": float(x.max()),
        "mean": float(x.mean()),
    }
