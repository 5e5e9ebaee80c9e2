"""The hole order (planning/tour.py): OR-tools' open path from a fixed start against the exact
optimum by enumeration."""

import numpy as np
import pytest

from marionette.planning.tour import brute_force_order, path_cost, tsp_order


@pytest.mark.parametrize("seed", range(6))
def test_open_path_matches_the_brute_force_optimum(seed):
    rng = np.random.default_rng(seed)
    n = 6 + seed % 3
    points = rng.uniform(-1, 1, (n, 3))
    costs = np.linalg.norm(points[:, None] - points[None], axis=2)
    start = int(rng.integers(n))
    order = tsp_order(costs, start, time_limit_s=0.5)
    assert sorted(order) == [i for i in range(n) if i != start]
    assert path_cost(costs, order, start) == pytest.approx(
        path_cost(costs, brute_force_order(costs, start), start), abs=1e-5
    )


def test_asymmetric_costs_and_the_free_end():
    # a line of targets: from the start at one end the optimum is to walk the line, not return
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    costs = np.abs(x[:, None] - x[None])
    assert tsp_order(costs, 0) == [1, 2, 3, 4]
    assert tsp_order(costs, 2, time_limit_s=0.3) in ([1, 0, 3, 4], [3, 4, 1, 0])
    # one-way costs: going "down" is 10x dearer
    asym = np.where(x[:, None] < x[None], costs, 10 * costs)
    order = tsp_order(asym, 2, time_limit_s=0.3)
    assert path_cost(asym, order, 2) == pytest.approx(
        path_cost(asym, brute_force_order(asym, 2), 2)
    )


def test_bad_costs_are_refused():
    with pytest.raises(ValueError, match="square"):
        tsp_order(np.ones((3, 4)))
    with pytest.raises(ValueError, match="finite"):
        tsp_order(np.array([[0, np.nan], [1, 0]]))
    with pytest.raises(ValueError, match="start"):
        tsp_order(np.zeros((3, 3)), start=5)
