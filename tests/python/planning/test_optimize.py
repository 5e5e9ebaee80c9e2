"""Path optimisation keeps transition semantics; the time parameterisation keeps the limits."""

from __future__ import annotations

import itertools

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette.planning.collision import CollisionChecker
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.hpp_export import arm_indices
from marionette.planning.optimize import (
    arm_path_length,
    optimize_paths,
    partial_shortcut,
)
from marionette.planning.planner import ManipulationRRT
from marionette.planning.problem import load_problem
from marionette.planning.timing import Limits, _profile_time, time_parameterize

PROBLEMS = marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems"


@pytest.fixture(scope="module")
def ur10():
    problem = load_problem(PROBLEMS / "ur10_box.yaml")
    graph = graph_from_settings(problem)
    graph.initialize()
    return problem, graph, CollisionChecker(problem)


def state_sequence(graph, paths):
    """Graph states at the path boundaries, consecutive repeats merged."""
    names = [graph.state_of(paths[0].start).name] + [graph.state_of(p.end).name for p in paths]
    return [k for k, _ in itertools.groupby(names)]


def check_plan(problem, graph, checker, paths, step=0.01):
    assert np.allclose(paths[0].start, problem.q_init)
    assert np.allclose(paths[-1].end, problem.q_goal, atol=1e-6)
    for a, b in zip(paths, paths[1:]):
        assert np.array_equal(a.end, b.start)
    for p in paths:
        proj = p.edge.path_projector
        proj.set_rhs_from(p.start)
        allowed = checker.grasp_contact_pairs(p.edge.grasps)
        for q in p.sample(step)[1]:
            assert proj.is_satisfied(q, 2 * graph.error_threshold), p.edge.name
            assert checker.is_valid(q, allowed), p.edge.name


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_optimisation_keeps_the_transitions_and_shortens(ur10, seed):
    problem, graph, checker = ur10
    r = ManipulationRRT(problem, graph, checker, seed=seed).solve(
        problem.q_init, [problem.q_goal], 2000, 60
    )
    assert r.success
    opt = optimize_paths(r.paths, graph, checker, np.random.default_rng(seed))
    check_plan(problem, graph, checker, opt)
    assert sum(p.length for p in opt) <= r.length + 1e-9
    arm = arm_indices(problem)
    assert arm_path_length(opt, arm) <= arm_path_length(r.paths, arm) + 1e-6
    # Same manipulation: grasp then release, through the same states in the same order
    # (the roadmap's detours are gone, never a grasp or a release).
    raw, new = state_sequence(graph, r.paths), state_sequence(graph, opt)
    assert new == ["free", "ur10/gripper grasps box/top", "free"]
    assert set(new) <= set(raw)
    # Approaches stay straight: every pre-grasp -> grasp sub-path is one segment.
    for p in opt:
        if p.edge.name.endswith(("_12", "_21")):
            assert len(p.points) == 2


def test_partial_shortcut_moves_one_joint_at_a_time_and_stays_valid(ur10):
    problem, graph, checker = ur10
    r = ManipulationRRT(problem, graph, checker, seed=5).solve(
        problem.q_init, [problem.q_goal], 2000, 60
    )
    assert r.success
    out = partial_shortcut(r.paths, checker, np.random.default_rng(0), iterations=60)
    check_plan(problem, graph, checker, out)
    assert sum(p.length for p in out) <= r.length + 1e-9


@pytest.mark.parametrize(
    "length, v, a",
    [(1.0, 0.5, 2.0), (0.05, 1.0, 1.0), (2.0, np.inf, 1.0), (3.0, 1.5, np.inf)],
)
def test_profile_is_the_closed_form_trapezoid(length, v, a):
    s = np.linspace(0.0, length, 2001)
    t = _profile_time(s, length, v, a)
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    if np.isfinite(a) and np.isfinite(v) and v * v / a < length:
        total = length / v + v / a  # cruise + both ramps
    elif np.isfinite(a):
        total = 2.0 * np.sqrt(length / a)  # triangle
    else:
        total = length / v
    assert t[-1] == pytest.approx(total, rel=1e-12)
    speed = np.diff(s) / np.diff(t)
    if np.isfinite(v):
        assert speed.max() <= v * (1 + 1e-9)
    if np.isfinite(a):
        # s = a t^2 / 2 on the first ramp: a closed form of the times
        ramp = s <= min(length / 2, v * v / (2 * a) if np.isfinite(v) else length / 2)
        np.testing.assert_allclose(t[ramp], np.sqrt(2 * s[ramp] / a), rtol=1e-12)


def test_timed_plan_keeps_every_joint_within_its_limits(ur10):
    problem, graph, checker = ur10
    r = ManipulationRRT(problem, graph, checker, seed=2).solve(
        problem.q_init, [problem.q_goal], 2000, 60
    )
    paths = optimize_paths(r.paths, graph, checker, np.random.default_rng(2))
    limits = Limits.of_robots(problem, acceleration=1.5, velocity_scale=0.5)
    samples = [np.linspace(0.0, p.length, 400) for p in paths]
    times, durations = time_parameterize(paths, limits, samples)
    assert all(d > 0 for d in durations)
    t_end = 0.0
    for p, s, t, d in zip(paths, samples, times, durations):
        assert t[0] == pytest.approx(t_end) and t[-1] == pytest.approx(t_end + d)
        t_end = t[-1]
        qs = np.array([p.eval(x) for x in s])
        dv = np.array([pin.difference(problem.model, a, b) for a, b in zip(qs, qs[1:])])
        vel = dv / np.diff(t)[:, None]
        arm = np.isfinite(limits.velocity)
        assert np.all(np.abs(vel[:, arm]) <= limits.velocity[arm] * (1 + 1e-6)), p.edge.name
        acc = np.diff(vel, axis=0) / (0.5 * (np.diff(t)[1:] + np.diff(t)[:-1]))[:, None]
        # second differences straddle the ramp switches: 2 % slack
        assert np.all(np.abs(acc[:, arm]) <= limits.acceleration[arm] * 1.02), p.edge.name
        # at rest at both ends (a transition ends where the controller switches)
        assert np.all(np.abs(vel[0, arm]) < 0.05 * limits.velocity[arm])
        assert np.all(np.abs(vel[-1, arm]) < 0.05 * limits.velocity[arm])
