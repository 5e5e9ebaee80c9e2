"""TALOS turns the plank upside down (thesis §3.4): planned with feet fixed and CoM balanced."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette.planning.collision import CollisionChecker
from marionette.planning.constraints import Kinematics
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.guide import guide_configuration, plan_through
from marionette.planning.problem import load_problem

PROBLEM = (
    marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems" / "talos_plank.yaml"
)


@pytest.fixture(scope="module")
def setup():
    problem = load_problem(PROBLEM)
    graph = graph_from_settings(problem)
    return problem, graph, CollisionChecker(problem)


def frame_pose(problem, kin, name):
    f = problem.model.frames[problem.frame_id(name)]
    return kin.data.oMi[f.parentJoint] * f.placement


def test_guide_waypoint_holds_the_plank_with_both_hands_balanced(setup):
    problem, graph, checker = setup
    entry = next(e for e in problem.settings["guide"] if " : " in e["state"])  # two hands
    q = guide_configuration(
        problem, graph, checker, entry, problem.q_init, np.random.default_rng(0)
    )
    state = graph.states[entry["state"]]
    assert state.contains(q) and len(state.grasps) == 2
    kin = Kinematics(problem.model)
    kin.update(problem.q_init)
    com0 = kin.com().copy()
    feet0 = [frame_pose(problem, kin, f) for f in ("talos/left_sole_link", "talos/right_sole_link")]
    kin.update(q)
    for name, X0 in zip(("talos/left_sole_link", "talos/right_sole_link"), feet0):
        assert np.linalg.norm(pin.log6(X0.actInv(frame_pose(problem, kin, name))).vector) < 1e-3
    assert np.linalg.norm(kin.com()[:2] - com0[:2]) < 1e-3


@pytest.mark.slow
def test_plank_flip_is_planned_with_feet_fixed_and_com_balanced(setup):
    problem, graph, checker = setup
    # Seed 4 plans in a few seconds; across seeds 1-4 planning took 2 s to 3 min (RRT
    # variance, see the planning README): the checks below hold for any plan.
    rng = np.random.default_rng(4)
    waypoints = [
        guide_configuration(problem, graph, checker, e, problem.q_init, rng)
        for e in problem.settings["guide"]
    ]
    result = plan_through(
        problem,
        graph,
        checker,
        [problem.q_init, *waypoints, problem.q_goal],
        seed=4,
        max_iterations=100000,
        timeout_s=500,
    )
    assert result.success, result.reason
    paths = result.paths
    kin = Kinematics(problem.model)
    kin.update(problem.q_init)
    com0 = kin.com()[:2].copy()
    feet0 = [frame_pose(problem, kin, f) for f in ("talos/left_sole_link", "talos/right_sole_link")]
    two_hands = False
    for p in paths:
        end_state = graph.state_of(p.end)
        two_hands |= end_state is not None and len(end_state.grasps) == 2
        allowed = checker.grasp_contact_pairs(p.edge.grasps)
        for q in p.sample(0.05)[1]:
            kin.update(q)
            # Feet never move and the CoM stays over them (quasi-static balance), everywhere.
            for name, X0 in zip(("talos/left_sole_link", "talos/right_sole_link"), feet0):
                err = pin.log6(X0.actInv(frame_pose(problem, kin, name))).vector
                assert np.linalg.norm(err) < 2e-3, p.edge.name
            assert np.linalg.norm(kin.com()[:2] - com0) < 2e-3, p.edge.name
            assert checker.is_valid(q, allowed), p.edge.name
    assert two_hands, "the plank is turned by handing it over from one hand to the other"
    # The plank ends upside down: its front end, up at the start, rests on the table.
    plank = problem.objects["plank"]
    X_end = pin.XYZQUATToSE3(paths[-1].end[plank.idx_q : plank.idx_q + 7])
    X_start = pin.XYZQUATToSE3(problem.q_init[plank.idx_q : plank.idx_q + 7])
    assert X_start.rotation[2, 0] == pytest.approx(1.0, abs=1e-6)  # plank x axis up
    assert X_end.rotation[2, 0] == pytest.approx(-1.0, abs=1e-3)  # plank x axis down
