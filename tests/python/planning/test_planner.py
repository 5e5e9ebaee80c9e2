"""Manipulation-RRT on the UR5 box benchmark: success rate and the validity of every plan."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import marionette
from marionette.planning.collision import CollisionChecker
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.optimize import graph_shortcut, random_shortcut
from marionette.planning.path import load_plan, save_plan
from marionette.planning.planner import ManipulationRRT, PlanningError


@pytest.fixture(scope="module")
def setup(ur5_box):
    graph = graph_from_settings(ur5_box)
    graph.initialize()
    return ur5_box, graph, CollisionChecker(ur5_box)


def check_plan(problem, graph, checker, paths, step=0.01):
    """Independent checks of a plan: continuity, ends, constraints and collisions sampled."""
    assert np.allclose(paths[0].start, problem.q_init)
    assert np.allclose(paths[-1].end, problem.q_goal, atol=1e-6)
    for a, b in zip(paths, paths[1:]):
        assert np.allclose(a.end, b.start, atol=1e-9)
    for p in paths:
        proj = p.edge.path_projector
        proj.set_rhs_from(p.start)
        _, qs = p.sample(step)
        allowed = checker.grasp_contact_pairs(p.edge.grasps)
        for q in qs:
            assert proj.is_satisfied(q, 2 * graph.error_threshold), p.edge.name
            assert checker.is_valid(q, allowed), p.edge.name


def dedup(names):
    return [k for k, _ in itertools.groupby(names)]


def test_ur5_box_is_solved_for_at_least_19_of_20_seeds(setup):
    problem, graph, checker = setup
    results = [
        ManipulationRRT(problem, graph, checker, seed=s).solve(
            problem.q_init, [problem.q_goal], max_iterations=1000, timeout_s=30
        )
        for s in range(20)
    ]
    assert sum(r.success for r in results) >= 19
    for r in results[:5]:
        if r.success:
            check_plan(problem, graph, checker, r.paths)
            # Pick then place: the box is grasped, carried, released.
            tops = dedup([(p.edge.parent or p.edge).name for p in r.paths])
            assert any(" > " in t for t in tops) and any(" < " in t for t in tops)


def test_shortcut_keeps_transitions_and_shortens(setup):
    problem, graph, checker = setup
    r = ManipulationRRT(problem, graph, checker, seed=4).solve(problem.q_init, [problem.q_goal])
    assert r.success
    short = random_shortcut(r.paths, checker, np.random.default_rng(0), iterations=30)
    assert sum(p.length for p in short) <= r.length + 1e-9
    assert dedup([p.edge.name for p in short]) == dedup([p.edge.name for p in r.paths])
    check_plan(problem, graph, checker, short)


def test_plan_file_round_trip(setup, tmp_path):
    problem, graph, checker = setup
    r = ManipulationRRT(problem, graph, checker, seed=2).solve(problem.q_init, [problem.q_goal])
    json_path, _npz_path = save_plan(tmp_path / "plan", graph, r.paths, step=0.02)
    plan = load_plan(json_path)
    assert plan.transitions == [p.edge.name for p in r.paths]
    doc = plan.doc
    assert doc["format"] == "marionette-plan/1"
    assert doc["problem"]["configuration_layout"][6] == "box/root_joint.x"
    for entry, p, (s, qs) in zip(doc["paths"], r.paths, plan.paths):
        assert qs.shape[1] == problem.nq
        assert np.allclose(qs[0], p.start) and np.allclose(qs[-1], p.end)
        assert s[-1] == pytest.approx(p.length)
        assert entry["containing_state"] == p.edge.containing.name
        assert entry["start_state"] is not None and entry["end_state"] is not None
    # Transfer paths carry the grasp, transit paths the box's held pose (locked joint value).
    kinds = {e["containing_state"]: e for e in doc["paths"]}
    assert kinds["ur5/gripper grasps box/handle"]["grasps"] == {"ur5/gripper": "box/handle"}
    assert "place_box/hold" in kinds["free"]["rhs"]
    # Constraint definitions a controller builds its tasks from: the grasp is the gripper
    # frame on the handle frame, given by joints and constant placements.
    grasp = doc["graph"]["constraint_definitions"]["ur5/gripper grasps box/handle"]
    assert grasp["type"] == "ExplicitRelativePose"
    assert (
        grasp["parent_joint"] == "ur5/wrist_3_joint" and grasp["output_joint"] == "box/root_joint"
    )
    pregrasp = doc["graph"]["constraint_definitions"]["ur5/gripper pregrasps box/handle"]
    assert pregrasp["joint1"] == "ur5/wrist_3_joint" and all(pregrasp["mask"])


def test_start_in_collision_or_in_no_state_is_refused(setup):
    problem, graph, checker = setup
    q = problem.q_init.copy()
    q[8] = 0.3  # box floating: on no placement, not grasped
    with pytest.raises(PlanningError, match="no state"):
        ManipulationRRT(problem, graph, checker).solve(q, [problem.q_goal])
    q = problem.q_init.copy()
    q[8] = 0.0251
    q[6:8] = [0.0, 0.0]  # box inside the robot base... and outside the table: no state
    with pytest.raises(PlanningError):
        ManipulationRRT(problem, graph, checker).solve(q, [problem.q_goal])


def test_ur10_box_moved_across_the_table_in_at_least_19_of_20_seeds():
    """The models' UR10 (two-finger gripper) moves the box 0.5 m across the models' table."""
    from marionette.planning.problem import load_problem

    problem = load_problem(
        marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems" / "ur10_box.yaml"
    )
    graph = graph_from_settings(problem)
    graph.initialize()
    checker = CollisionChecker(problem)
    results = [
        ManipulationRRT(problem, graph, checker, seed=s).solve(
            problem.q_init, [problem.q_goal], max_iterations=2000, timeout_s=60
        )
        for s in range(20)
    ]
    assert sum(r.success for r in results) >= 19, [r.reason for r in results if not r.success]
    check_plan(problem, graph, checker, next(r for r in results if r.success).paths)


def test_graph_shortcut_keeps_a_valid_pick_and_place(setup):
    """Shortcuts across transitions: still a valid plan from start to goal, never longer, and
    the box is still grasped then released through the pre-grasp waypoints."""
    problem, graph, checker = setup
    r = ManipulationRRT(problem, graph, checker, seed=0).solve(problem.q_init, [problem.q_goal])
    assert r.success
    short = graph_shortcut(r.paths, graph, checker, np.random.default_rng(1), iterations=40)
    assert sum(p.length for p in short) <= r.length + 1e-9
    check_plan(problem, graph, checker, short)
    names = [p.edge.name for p in short]
    assert any(n.endswith("_12") for n in names) and any(n.endswith("_21") for n in names)
