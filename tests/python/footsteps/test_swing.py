"""Eq. 5.1 (sole over a bar) against brute-force geometry, and the crossing passage points."""

from __future__ import annotations

import numpy as np
import pytest

from footsteps_checks import TALOS_FOOT
from marionette.footsteps.errors import InvalidProblem
from marionette.footsteps.obstacles import Bar
from marionette.footsteps.swing import bar_clearance, crossing_via_points

R, D1, D2 = 0.03, 0.08, 0.13  # bar radius, heel and toe distances of the sole point O


def _collides(s: float, h: float) -> bool:
    """Brute force: does the sole segment [s − d1, s + d2] at height h meet the bar (a disc of
    radius R on the floor, completed down to the floor as in eq. 5.2)?"""
    xs = np.linspace(s - D1, s + D2, 801)
    in_disc = xs**2 + (h - R) ** 2 < R**2
    under_disc = (np.abs(xs) < R) & (h < R)
    return bool(np.any(in_disc | under_disc))


def test_eq_5_1_clearance_sign_matches_brute_force():
    rng = np.random.default_rng(0)
    s = rng.uniform(-0.4, 0.4, 3000)
    h = rng.uniform(0.0, 0.1, 3000)
    value = bar_clearance(s, h, s_c=0.0, h_c=R, radius=R, d1=D1, d2=D2)
    brute = np.array([_collides(a, b) for a, b in zip(s, h)])
    decided = np.abs(value) > 2e-3  # away from the boundary, up to sampling error
    assert np.all((value[decided] < 0.0) == brute[decided])
    assert 100 < brute.sum() < 2900  # both outcomes sampled


def test_crossing_passage_points_keep_the_swinging_sole_clear():
    bar = Bar([1.0, 0.2], 1.7, R, 2.0, buffer=0.03)
    n = bar.normal()
    half = 0.5 * TALOS_FOOT.length
    lift = np.array(
        [*(bar.center - (R + half + 0.05) * n + 0.03 * n[::-1]), 0.0, bar.yaw - np.pi / 2]
    )
    land = np.array(
        [*(bar.center + (R + half + 0.06) * n - 0.02 * n[::-1]), 0.0, bar.yaw - np.pi / 2]
    )
    via, apex = crossing_via_points(lift, land, bar, TALOS_FOOT.length, TALOS_FOOT.width, 0.03)
    assert via.shape == (2, 3) and apex == pytest.approx(2 * R + 0.03)
    # Sample the polyline lift-off → via₁ → via₂ → landing in the bar's cross-section.
    points = np.vstack([lift[:3], via, land[:3]])
    path = np.vstack([np.linspace(a, b, 200) for a, b in zip(points[:-1], points[1:])])
    s = (path[:, :2] - bar.center) @ n
    value = bar_clearance(s, path[:, 2], 0.0, R, R, half, half)
    assert np.min(value) >= 0.03 - 1e-9


def test_crossing_needs_the_feet_on_both_sides():
    bar = Bar([1.0, 0.0], np.pi / 2, R, 2.0)
    with pytest.raises(InvalidProblem, match="same side"):
        crossing_via_points(np.array([0.5, 0, 0, 0]), np.array([0.7, 0, 0, 0]), bar, 0.21, 0.13)
