"""Walking measures used by the grasp-walk verdict, against independent references: the ZMP
margin against brute-force distances to the polygon's edges, the merged plan against the footstep
manager's rules, the sole size against the MJCF, the reach's minimum-jerk law against finite
differences."""

from __future__ import annotations

import numpy as np
import pytest

from marionette import lcmt_footstep, lcmt_footstep_plan, robots
from marionette.execution.references import minimum_jerk
from marionette.execution.walking import MergedPlan, polygon_margin, sole_corners, sole_half_size


def _segment_distance(p, a, b) -> float:
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * (b - a))))


def test_zmp_margin_is_the_signed_distance_to_the_support_polygon():
    rng = np.random.default_rng(3)
    half = (0.1025, 0.061)
    feet = [np.array([0.1, 0.09, 0.0, 0.2]), np.array([0.25, -0.08, 0.0, -0.1])]
    corners = np.vstack([sole_corners(f, half) for f in feet])
    from scipy.spatial import ConvexHull

    hull = corners[ConvexHull(corners).vertices]  # counter-clockwise
    edges = list(zip(hull, np.roll(hull, -1, axis=0)))
    for p in rng.uniform([-0.1, -0.25], [0.45, 0.25], size=(300, 2)):
        d = min(_segment_distance(p, a, b) for a, b in edges)
        inside = all((b - a)[0] * (p - a)[1] - (b - a)[1] * (p - a)[0] >= 0 for a, b in edges)
        m = polygon_margin(p, corners)
        if inside:
            # Inside, the margin is the distance to the nearest edge line = nearest edge.
            assert m == pytest.approx(d, abs=1e-12)
        else:
            assert m < 0 and -m <= d + 1e-12  # outside: negative, at most the true distance


def test_sole_corners_rotate_with_the_yaw():
    c = sole_corners([1.0, 2.0, 0.0, np.pi / 2], (0.1, 0.05))
    assert np.allclose(
        sorted(map(tuple, np.round(c, 12))),
        sorted([(1.05, 2.1), (0.95, 2.1), (1.05, 1.9), (0.95, 1.9)]),
    )


def test_sole_size_comes_from_the_mjcf_and_bad_names_are_named(tmp_path):
    assert sole_half_size(robots.robot("talos").mjcf) == (0.1025, 0.061)
    with pytest.raises(ValueError, match="no geom named 'left_toe'"):
        sole_half_size(robots.robot("talos").mjcf, "left_toe")


def _plan(first: int, indices, x: float):
    msg = lcmt_footstep_plan()
    msg.first_step_index = first
    for i in indices:
        s = lcmt_footstep()
        s.index, s.is_left, s.x, s.y, s.z, s.yaw = i, i % 2 == 1, x + 0.1 * i, 0.0, 0.0, 0.0
        msg.steps.append(s)
    msg.num_steps = len(msg.steps)
    return msg


def test_merged_plan_keeps_started_steps_like_the_footstep_manager():
    merged = MergedPlan()
    merged.apply(_plan(0, range(6), 0.0), -1)
    # A replan from step 2 arriving while step 2 has already started: step 2 is kept.
    merged.apply(_plan(2, range(2, 8), 1.0), 2)
    xs = {i: s.x for i, s in merged.steps.items()}
    assert xs[2] == pytest.approx(0.2) and xs[3] == pytest.approx(1.3) and max(xs) == 7
    # A shorter replan drops the old tail.
    merged.apply(_plan(4, range(4, 6), 2.0), 3)
    assert sorted(merged.steps) == list(range(6)) and merged.steps[5].x == pytest.approx(2.5)
    stance = merged.final_stance({"left": np.zeros(4), "right": np.ones(4)})
    assert stance["left"][0] == pytest.approx(2.5) and stance["right"][0] == pytest.approx(2.4)


def test_minimum_jerk_derivatives_match_finite_differences():
    p0, p1 = np.array([0.1, -0.2, 0.9]), np.array([0.5, -0.3, 0.8])
    values, derivatives = minimum_jerk(p0, p1, 3.0, 1e-3)
    assert values.shape == (3001, 3)
    assert np.allclose(values[0], p0) and np.allclose(values[-1], p1)
    assert np.allclose(derivatives[[0, -1]], 0.0)
    fd = (values[2:] - values[:-2]) / 2e-3
    assert np.max(np.abs(fd - derivatives[1:-1])) < 1e-6


def test_seeded_floor_moves_cover_every_direction_within_their_distances():
    """Objects "moved by up to 0.3 m while walking": each trial's move is 0.1-0.3 m in any
    direction, the same for the same seed, and over many seeds every quadrant and both ends of the range
    are drawn."""
    from marionette.scenarios.walking_scenario import draw_floor_move

    moves = np.array([draw_floor_move(seed) for seed in range(400)])
    distance = np.linalg.norm(moves, axis=1)
    assert np.all((distance >= 0.1) & (distance <= 0.3))
    assert distance.min() < 0.11 and distance.max() > 0.29
    quadrants = {(bool(x > 0), bool(y > 0)) for x, y in moves}
    assert len(quadrants) == 4
    assert np.array_equal(draw_floor_move(7), draw_floor_move(7))
    with pytest.raises(ValueError, match="min_distance"):
        draw_floor_move(0, max_distance=0.1, min_distance=0.2)


def test_bar_height_under_a_sole_is_the_cylinder_or_an_end_block():
    """The step-over verdict's bar height under a horizontal sole, against the closed form of a
    cylinder of radius R lying on the floor: 2R over the axis, R + sqrt(R² − u²) at u from it, 0
    beyond R; the 7 cm end blocks beyond the cylinder's ends."""
    from marionette.scenarios.step_over import cylinder_height_under

    R, length, block = 0.025, 1.34, 0.07
    bar = (1.0, 0.0, np.pi / 2)  # axis along y

    def sole(x0, x1, y0=-0.05, y1=0.05):
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])

    assert cylinder_height_under(sole(0.9, 1.1), bar, R, length, block) == pytest.approx(2 * R)
    for u in (0.0, 0.01, 0.02, 0.0249):
        expected = R + np.sqrt(R * R - u * u)
        assert cylinder_height_under(sole(1.0 + u, 1.2), bar, R, length, block) == pytest.approx(
            expected
        )
        assert cylinder_height_under(sole(0.8, 1.0 - u), bar, R, length, block) == pytest.approx(
            expected
        )
    assert cylinder_height_under(sole(1.03, 1.2), bar, R, length, block) == 0.0
    assert cylinder_height_under(
        sole(0.9, 1.1, 0.62, 0.66), bar, R, length, block
    ) == pytest.approx(block)
