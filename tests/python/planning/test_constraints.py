"""Every constraint Jacobian against central finite differences on the configuration manifold."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette.planning.constraints import (
    ComPosition,
    ExplicitRelativePose,
    Kinematics,
    LockedJoint,
    Placement,
    PlacementComplement,
    RelativeTransformation,
    Transformation,
)
from marionette.planning.problem import random_configuration


def finite_difference_jacobian(constraint, kin, q, eps=1e-6):
    """Central differences of compute_error along each tangent direction (q (+) eps e_i)."""
    model = kin.model
    J = np.zeros((constraint.size, model.nv))
    for i in range(model.nv):
        dv = np.zeros(model.nv)
        dv[i] = eps
        kin.update(pin.integrate(model, q, dv), jacobians=False)
        fp = constraint.compute_error(kin)
        kin.update(pin.integrate(model, q, -dv), jacobians=False)
        fm = constraint.compute_error(kin)
        J[:, i] = (fp - fm) / (2 * eps)
    return J


def analytic_jacobian(constraint, kin, q):
    kin.update(q)
    return constraint.compute_jacobian(kin)


def constraints_under_test(p):
    g = p.grippers["ur5/gripper"]
    h = p.handles["box/handle"]
    mg = p.model.frames[g.frame_id].placement
    mh = p.model.frames[h.frame_id].placement
    place = Placement("place_box", p, "box", ["box/bottom"], ["table/top"], margin=1e-4)
    comp = PlacementComplement("place_box/complement", place)
    grasp = ExplicitRelativePose("grasp", p.model, h.joint_id, g.joint_id, mg, mh)
    lock = LockedJoint(
        "lock_box", p.model, p.objects["box"].joint_id, np.array([0.5, 0, 0.1, 0, 0, 0, 1])
    )
    lock_arm = LockedJoint("lock_elbow", p.model, 3, np.array([0.3]))
    return {
        "relative_transformation_6d": RelativeTransformation("rt", g.joint_id, mg, h.joint_id, mh),
        "relative_transformation_mask": RelativeTransformation(
            "rt_mask", g.joint_id, mg, h.joint_id, mh, mask=(True, False, True, False, True, True)
        ),
        "transformation": Transformation(
            "tf", g.joint_id, mg, pin.SE3(pin.utils.rotate("x", 0.4), np.array([0.4, 0.1, 0.3]))
        ),
        "placement": place,
        "placement_complement": comp,
        "grasp_as_implicit": grasp.as_implicit(),
        "locked_freeflyer_as_implicit": lock.as_implicit(),
        "locked_revolute_as_implicit": lock_arm.as_implicit(),
        "com_in_wrist_frame": ComPosition(
            "com", 5, pin.SE3(pin.utils.rotate("y", 0.3), np.array([0.1, 0.0, 0.05]))
        ),
        "com_in_world_xy": ComPosition("com_xy", 0, pin.SE3.Identity(), mask=(True, True, False)),
    }


@pytest.mark.parametrize(
    "which",
    [
        "relative_transformation_6d",
        "relative_transformation_mask",
        "transformation",
        "placement",
        "placement_complement",
        "grasp_as_implicit",
        "locked_freeflyer_as_implicit",
        "locked_revolute_as_implicit",
        "com_in_wrist_frame",
        "com_in_world_xy",
    ],
)
def test_jacobian_matches_finite_differences(ur5_box, which):
    c = constraints_under_test(ur5_box)[which]
    kin = Kinematics(ur5_box.model)
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = random_configuration(ur5_box, rng)
        J = analytic_jacobian(c, kin, q)
        J_fd = finite_difference_jacobian(c, kin, q)
        assert J.shape == (c.size, ur5_box.nv)
        np.testing.assert_allclose(J, J_fd, atol=2e-6, rtol=1e-5, err_msg=which)


def test_explicit_grasp_puts_handle_on_gripper(ur5_box):
    p = ur5_box
    g, h = p.grippers["ur5/gripper"], p.handles["box/handle"]
    grasp = ExplicitRelativePose(
        "grasp",
        p.model,
        h.joint_id,
        g.joint_id,
        p.model.frames[g.frame_id].placement,
        p.model.frames[h.frame_id].placement,
    )
    kin = Kinematics(p.model)
    q = random_configuration(p, np.random.default_rng(1))
    kin.update(q, jacobians=False)
    grasp.apply(kin, q)
    data = p.model.createData()
    pin.framesForwardKinematics(p.model, data, q)
    X_G, X_H = data.oMf[g.frame_id], data.oMf[h.frame_id]
    assert X_G.isApprox(X_H, 1e-12)


def test_placement_is_zero_for_box_resting_on_table(ur5_box):
    place = Placement("p", ur5_box, "box", ["box/bottom"], ["table/top"], margin=1e-4)
    kin = Kinematics(ur5_box.model)
    kin.update(ur5_box.q_init, jacobians=False)
    np.testing.assert_allclose(place.compute_error(kin), 0.0, atol=1e-12)
    assert place.inside(kin)
    comp = PlacementComplement("c", place)
    # Complement = position on the table (x, y in the table surface frame) and yaw: moving the
    # box 0.5 m along y moves the complement by 0.5 m, the placement error stays 0.
    kin.update(ur5_box.q_goal, jacobians=False)
    v_goal = comp.value(kin)
    kin.update(ur5_box.q_init, jacobians=False)
    assert np.linalg.norm(v_goal[:2] - comp.value(kin)[:2]) == pytest.approx(0.5, abs=1e-12)


@pytest.mark.parametrize("xy", [(1.2, 0.1), (1.2, 0.9), (0.5, -0.9)])
def test_placement_jacobian_outside_the_surface_polygon(ur5_box, xy):
    """Off the table, the placement pulls the box centre back onto the polygon (edge: rows
    n n^T, corner: identity); its Jacobian there still matches finite differences."""
    place = Placement("place_box", ur5_box, "box", ["box/bottom"], ["table/top"], margin=1e-4)
    kin = Kinematics(ur5_box.model)
    q = ur5_box.q_init.copy()
    q[6:8] = xy
    q[8] = 0.1
    kin.update(q, jacobians=False)
    e = place.compute_error(kin)
    assert np.linalg.norm(e[3:]) > 0.1  # offset to the table polygon is reported
    J = analytic_jacobian(place, kin, q)
    np.testing.assert_allclose(J, finite_difference_jacobian(place, kin, q), atol=2e-6)
