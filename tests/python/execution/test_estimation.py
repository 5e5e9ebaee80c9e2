"""Initial-state estimation (thesis 000 §3.2.2): perturbed measurements project onto the right
graph state, and the plan resumes at the right step (steps already done are skipped)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette.execution.estimation import (
    estimate_state,
    first_step_to_run,
    measured_configuration,
)
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.problem import load_problem


@pytest.fixture(scope="module")
def ur10_graph(ur10_box):
    return graph_from_settings(load_problem(ur10_box.plan.doc["problem"]["source"]))


def _perturbed(p, q_plan, rng):
    """Encoders off by ~2 mrad, the box seen 2 mm / 0.5° away."""
    q_robot = p.robot_map.robot_q(q_plan) + rng.normal(0.0, 0.002, p.model.nq)
    X = p.robot_map.object_pose(q_plan, "box")
    X = X * pin.exp6(np.r_[rng.normal(0, 0.002, 3), rng.normal(0, np.radians(0.5), 3)])
    return measured_configuration(q_plan, p.robot_map, q_robot, {"box": X})


def test_perturbed_start_of_each_step_is_recognised_and_resumed(ur10_box, ur10_graph):
    p = ur10_box
    rng = np.random.default_rng(3)
    for step in p.steps:
        estimate = estimate_state(ur10_graph, _perturbed(p, step.q[0], rng))
        expected = {step.start_state}
        if step.kind == "release" or step.transition.endswith("_23"):
            expected |= {"free", "ur10/gripper grasps box/top"}  # box grasped on the table: both
        assert estimate.state in expected, step.transition
        assert estimate.residual < 0.05
        assert first_step_to_run(p.steps, p.robot_map, estimate) == step.index, step.transition


def test_box_already_at_the_goal_means_nothing_left_to_do(ur10_box, ur10_graph):
    p = ur10_box
    estimate = estimate_state(
        ur10_graph, _perturbed(p, p.steps[-1].q[-1], np.random.default_rng(1))
    )
    assert estimate.state == "free"
    assert first_step_to_run(p.steps, p.robot_map, estimate) == len(p.steps)


def test_box_in_the_gripper_is_the_grasp_state(ur10_box, ur10_graph):
    p = ur10_box
    carry = next(s for s in p.steps if s.transition.endswith("_34"))
    q = carry.q[len(carry.q) // 2]  # mid-transfer, box in the air
    estimate = estimate_state(ur10_graph, _perturbed(p, q, np.random.default_rng(2)))
    assert estimate.state == "ur10/gripper grasps box/top"
    ranking = dict(estimate.ranking)
    assert ranking["free"] is None or ranking["free"] > 2 * estimate.residual  # box 5 cm up
