"""The campaign's statistics against independent references: SciPy's Wilson interval, the score
test's equation solved numerically, the closed forms at 0 and n successes, Newcombe's table."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.stats import binomtest, norm

from marionette.campaigns.stats import describe, wilson_interval


@pytest.mark.parametrize("confidence", [0.8, 0.9, 0.95, 0.99])
def test_wilson_matches_scipy_and_the_score_test_on_random_counts(confidence):
    rng = np.random.default_rng(int(confidence * 100))
    z = norm.ppf(0.5 + confidence / 2)
    for _ in range(200):
        n = int(rng.integers(1, 2000))
        k = int(rng.integers(0, n + 1))
        lo, hi = wilson_interval(k, n, confidence)
        ref = binomtest(k, n).proportion_ci(confidence, method="wilson")
        assert lo == pytest.approx(ref.low, abs=1e-12) and hi == pytest.approx(ref.high, abs=1e-12)
        # The interval's ends are the rates p where the score statistic equals z.
        p_hat = k / n

        def score(p, p_hat=p_hat, n=n):
            return (p_hat - p) ** 2 - z * z * p * (1 - p) / n

        if 0 < k:
            assert lo == pytest.approx(brentq(score, 1e-15, p_hat - 1e-12), abs=1e-9)
        if k < n:
            assert hi == pytest.approx(brentq(score, p_hat + 1e-12, 1 - 1e-15), abs=1e-9)


def test_wilson_closed_forms_at_no_and_all_successes():
    z2 = norm.ppf(0.975) ** 2
    for n in (1, 5, 20, 1000):
        assert wilson_interval(0, n) == pytest.approx((0.0, z2 / (n + z2)), abs=1e-12)
        assert wilson_interval(n, n) == pytest.approx((n / (n + z2), 1.0), abs=1e-12)


def test_wilson_reproduces_newcombes_table():
    """Newcombe, Statistics in Medicine 17 (1998) 857-872, table II, method 3 (score)."""
    for (k, n), (lo, hi) in {
        (81, 263): (0.2553, 0.3662),
        (15, 148): (0.0624, 0.1605),
        (0, 20): (0.0, 0.1611),
        (1, 29): (0.0061, 0.1718),
    }.items():
        assert wilson_interval(k, n) == pytest.approx((lo, hi), abs=5e-5)


def test_wilson_refuses_impossible_counts_and_covers_everything_without_trials():
    assert wilson_interval(0, 0) == (0.0, 1.0)
    for k, n, c in ((3, 2, 0.95), (-1, 2, 0.95), (1, 2, 1.0), (1, 2, 0.0)):
        with pytest.raises(ValueError):
            wilson_interval(k, n, c)


def test_describe_is_numpys_summary():
    x = np.random.default_rng(3).normal(size=37)
    d = describe(list(x))
    assert d["n"] == 37 and d["min"] == x.min() and d["max"] == x.max()
    assert d["median"] == pytest.approx(np.median(x)) and d["mean"] == pytest.approx(x.mean())
    assert d["p90"] == pytest.approx(np.percentile(x, 90))
    assert describe([]) == {"n": 0}
