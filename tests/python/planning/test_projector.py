"""Newton-Raphson projection: convergence, substitution, step-size schedule, failures, bounds."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette.planning.constraints import LockedJoint, Transformation
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.problem import random_configuration
from marionette.planning.projector import ALGORITHM_1, LineSearch, ProjectionStatus, Projector


@pytest.fixture(scope="module")
def graph(ur5_box):
    return graph_from_settings(ur5_box)


def configuration_in(graph, state_name, rng):
    """A configuration of the state: project uniform samples until one succeeds."""
    s = graph.states[state_name]
    s.projector.set_rhs_from(graph.problem.q_init)
    for _ in range(500):
        q = random_configuration(graph.problem, rng)
        if s.project(q):
            return q
    raise AssertionError(f"no configuration found in {state_name}")


@pytest.mark.parametrize(
    "state_name",
    [
        "free",
        "ur5/gripper grasps box/handle",
        "ur5/gripper > box/handle | f_pregrasp",
        "ur5/gripper > box/handle | f_intersec",
        "ur5/gripper > box/handle | f_preplace",
    ],
)
def test_projection_converges_from_perturbed_configurations(graph, state_name):
    rng = np.random.default_rng(3)
    model = graph.problem.model
    s = graph.states[state_name]
    for _ in range(5):
        q_ref = configuration_in(graph, state_name, rng)
        assert s.contains(q_ref)
        q = pin.integrate(model, q_ref, 0.02 * rng.standard_normal(model.nv))
        result = s.project(q)
        assert result, f"{state_name}: {result}"
        assert s.contains(q)
        # A projector moves a nearby configuration a short way (Definition 3: close to q0).
        assert np.linalg.norm(pin.difference(model, q_ref, q)) < 0.2
        # Idempotence (Definition 4): projecting again does not move it.
        q2 = q.copy()
        assert s.project(q2)
        assert np.linalg.norm(pin.difference(model, q, q2)) < 1e-6


def test_grasp_state_is_solved_by_substitution_without_iterating(graph):
    s = graph.states["ur5/gripper grasps box/handle"]
    assert not s.projector.implicit  # the grasp is explicit: nothing to iterate
    q = random_configuration(graph.problem, np.random.default_rng(0))
    result = s.project(q)
    assert result.success and result.iterations == 0
    assert s.contains(q)


def test_fixed_sequence_follows_algorithm_1_schedule(ur5_box):
    """On a linear constraint (a locked joint, e = q_j - v), one Newton step with step alpha
    multiplies the error by (1 - alpha); Algorithm 1's alpha_k+1 = .95 - .8 (.95 - alpha_k)."""
    model = ur5_box.model
    lock = LockedJoint("elbow", model, model.getJointId("ur5/elbow_joint"), np.array([0.5]))
    proj = Projector(
        ur5_box,
        [lock.as_implicit()],
        error_threshold=1e-12,
        max_iterations=6,
        line_search=ALGORITHM_1,
        damping=0.0,
    )
    q = ur5_box.q_init.copy()
    e0 = q[2] - 0.5
    result = proj.project(q)
    assert result.status is ProjectionStatus.MAX_ITERATIONS
    alpha, expected = 0.1, e0
    for _ in range(6):
        expected *= 1.0 - alpha
        alpha = 0.95 - 0.8 * (0.95 - alpha)
    assert q[2] - 0.5 == pytest.approx(expected, rel=1e-9)


def test_unreachable_target_is_reported_not_crashing(ur5_box):
    g = ur5_box.grippers["ur5/gripper"]
    far = Transformation(
        "far",
        g.joint_id,
        ur5_box.model.frames[g.frame_id].placement,
        pin.SE3(np.eye(3), np.array([3.0, 0.0, 0.5])),
    )
    proj = Projector(ur5_box, [far], max_iterations=30)
    q = ur5_box.q_init.copy()
    result = proj.project(q)
    assert not result.success
    assert result.status in (
        ProjectionStatus.NOT_DECREASING,
        ProjectionStatus.MAX_ITERATIONS,
        ProjectionStatus.LOCAL_MINIMUM,
    )
    assert result.error_norm > 1.5  # the arm (reach < 1 m) cannot get within 1.5 m
    assert "iteration" in str(result) and "|e|" in str(result)


def test_projection_respects_joint_bounds(ur5_box):
    """A target reachable only by leaving a joint's range ends on the bound, never past it."""
    p = ur5_box
    model = p.model
    lock = LockedJoint("pan", model, model.getJointId("ur5/shoulder_pan_joint"), np.array([4.0]))
    proj = Projector(p, [lock.as_implicit()], max_iterations=20)
    q = p.q_init.copy()
    result = proj.project(q)
    assert not result.success
    assert p.lower[0] <= q[0] <= p.upper[0]
    assert q[0] == pytest.approx(p.upper[0])


def test_priority_levels_keep_the_first_level_when_levels_conflict(ur5_box):
    """Two incompatible targets for one joint: level 0 is met, level 1 is what is left."""
    model = ur5_box.model
    j = model.getJointId("ur5/elbow_joint")
    high = LockedJoint("high", model, j, np.array([0.4])).as_implicit()
    low = LockedJoint("low", model, j, np.array([0.9])).as_implicit()
    proj = Projector(ur5_box, [high, low], levels=[0, 1], max_iterations=20)
    q = ur5_box.q_init.copy()
    result = proj.project(q)
    assert not result.success
    assert q[2] == pytest.approx(0.4, abs=1e-6)


def test_bad_arguments_raise_precise_errors(ur5_box):
    with pytest.raises(ValueError, match="error_threshold"):
        Projector(ur5_box, [], error_threshold=0.0)
    with pytest.raises(ValueError, match="line search kind"):
        LineSearch("newton")
    with pytest.raises(ValueError, match="levels"):
        Projector(ur5_box, [LockedJoint("a", ur5_box.model, 1).as_implicit()], levels=[0, 1])
