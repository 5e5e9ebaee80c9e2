"""The pieces of a standing grasp (``scenarios/standing_grasp.py``) against independent
references: the streamed pose's derivatives by finite differences, the grasp orientation by its
defining properties and by brute force over both signs, the empty-hand check on every bundled
gripper with a joint, and the ball's resting height in the pedestal's cup by a sphere lowered
until it touches the cup's blocks."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest


def _random_pose(rng) -> pin.SE3:
    return pin.SE3(pin.exp3(rng.uniform(-np.pi, np.pi, 3)), rng.uniform(-1.0, 1.0, 3))


@pytest.mark.parametrize("seed", range(6))
def test_the_streamed_pose_starts_ends_and_moves_as_its_derivatives_say(seed):
    from marionette.scenarios.standing_grasp import pose_minimum_jerk

    rng = np.random.default_rng(seed)
    X0, X1 = _random_pose(rng), _random_pose(rng)
    dt = 1e-3
    values, derivatives = pose_minimum_jerk(X0, X1, int(rng.integers(500, 3000)) * dt, dt)

    def pose(row):
        w, x, y, z = row[3:]
        return pin.SE3(pin.Quaternion(w, x, y, z).normalized().matrix(), row[:3])

    assert pose(values[0]).isApprox(X0, 1e-9) and pose(values[-1]).isApprox(X1, 1e-9)
    assert np.allclose(derivatives[[0, -1]], 0.0, atol=1e-9), "at rest at both ends"
    for k in rng.integers(1, len(values) - 1, 25):
        a, b = pose(values[k - 1]), pose(values[k + 1])
        v = (b.translation - a.translation) / (2 * dt)
        w = pose(values[k]).rotation @ pin.log3(a.rotation.T @ b.rotation) / (2 * dt)
        assert np.allclose(derivatives[k, :3], v, atol=1e-5 * max(1.0, np.abs(v).max()))
        assert np.allclose(derivatives[k, 3:], w, atol=1e-5 * max(1.0, np.abs(w).max()))
    # One rotation axis throughout (the geodesic): every intermediate rotation is R0 exp(s w).
    axis = pin.log3(X0.rotation.T @ X1.rotation)
    for k in rng.integers(0, len(values), 10):
        rel = pin.log3(X0.rotation.T @ pose(values[k]).rotation)
        assert np.linalg.norm(np.cross(rel, axis)) < 1e-8


@pytest.mark.parametrize("seed", range(8))
def test_the_grasp_points_down_tilted_away_from_the_shoulder_nearest_the_hand(seed):
    from marionette.scenarios.standing_grasp import grasp_pose

    rng = np.random.default_rng(seed)
    p = np.array([*rng.uniform(-1.0, 1.0, 2), 0.9])
    shoulder = p + np.array([*rng.uniform(-0.6, 0.6, 2), 0.35])
    tilt = rng.uniform(0.0, 40.0)
    R_now = pin.exp3(rng.uniform(-np.pi, np.pi, 3))
    X = grasp_pose(p, shoulder, tilt, R_now)
    x, y, _ = X.rotation.T
    assert np.allclose(X.rotation.T @ X.rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(X.rotation) == pytest.approx(1.0)
    assert np.allclose(X.translation, p)
    assert np.degrees(np.arccos(-x[2])) == pytest.approx(tilt, abs=1e-9), "tilt from the vertical"
    away = (p - shoulder)[:2]
    assert x[:2] @ away >= -1e-12, "tilted away from the shoulder"
    assert abs(y[2]) < 1e-12, "the closing axis is horizontal"
    assert abs(y[:2] @ away) < 1e-9
    # Of the two horizontal closing directions, the one nearer the hand's current rotation.
    flipped = X.rotation @ np.diag([1.0, -1.0, -1.0])
    assert np.linalg.norm(pin.log3(R_now.T @ X.rotation)) <= np.linalg.norm(
        pin.log3(R_now.T @ flipped)
    )


def _bundled_gripper_joints():
    from marionette import robots
    from marionette.execution.factory import gripper_joint

    out = []
    for name in robots.robot_names():
        model, _ = robots.load_pinocchio(name, with_collision=False)
        for g in robots.semantics(name).grippers:
            if g.joint is not None and g.open_position is not None:
                out.append((f"{name}:{g.name}", gripper_joint(g, model, name)))
    return out


def test_fingers_at_their_closed_stop_hold_nothing_on_every_bundled_gripper():
    from marionette.scenarios.standing_grasp import grasp_check

    joints = _bundled_gripper_joints()
    assert len(joints) >= 4
    for name, j in joints:
        stroke = j.closed_position - j.open_position
        assert grasp_check(j, j.closed_position, 0.1) is not None, name
        assert grasp_check(j, j.closed_position - 0.05 * stroke, 0.1) is not None, name
        assert grasp_check(j, j.open_position + 0.5 * stroke, 0.1) is None, name
        assert grasp_check(j, j.closed_position - 0.2 * stroke, 0.1) is None, name


def test_the_grip_stack_frees_the_gripper_joint_from_the_posture():
    from marionette import robots
    from marionette.control.spec import ControllerSpec
    from marionette.execution.factory import gripper_joint
    from marionette.scenarios.standing_grasp import approach_spec, grip_spec

    model, _ = robots.load_pinocchio("talos", with_collision=False)
    g = robots.semantics("talos").gripper("talos/right_gripper")
    joint = gripper_joint(g, model, "talos")
    grip = grip_spec(3, "talos", g.link, joint, model)
    tasks = {t.name: t for t in grip.tasks}
    assert list(tasks["gripper_admittance"].joints) == [joint.joint]
    posture = tasks["posture"]
    one_dof = {model.names[j] for j in range(1, model.njoints) if model.joints[j].nv == 1}
    assert set(posture.joints) == one_dof - {joint.joint}
    assert [t.priority for t in grip.tasks if t.name in ("hand", "gripper_admittance")] == [1, 1]
    assert tasks["hand"].streamed and tasks["hand"].frame == g.link
    approach = {t.name: t for t in approach_spec(2, "talos", g.link).tasks}
    assert "gripper_admittance" not in approach and not approach["posture"].joints
    for spec in (grip, approach_spec(2, "talos", g.link)):
        spec.to_lcm(0)  # every field fits the message
        assert ControllerSpec.from_dict(spec.to_dict()).to_dict() == spec.to_dict()


def test_the_ball_rests_in_the_cup_where_a_lowered_sphere_first_touches_it():
    """Lower the ball's centre along the pedestal's axis until the sphere meets one of the cup's
    boxes (exact point-to-box distance), and compare with ``ball_rest_z``; the ball clears the
    plate below it, and the cup lies inside the ball's equator (fingers closing on the equator
    meet only the ball)."""
    from marionette.models.objects import Ball, Pedestal

    pedestal, ball = Pedestal(), Ball()
    boxes = [s for s in pedestal.shapes() if s.kind == "box"][1:]  # the column is the first
    assert len(boxes) == 6

    def distance(p):
        out = np.inf
        for b in boxes:
            X = np.asarray(b.X)
            local = X[:3, :3].T @ (p - X[:3, 3])
            half = np.asarray(b.size) / 2
            out = min(out, float(np.linalg.norm(np.maximum(np.abs(local) - half, 0.0))))
        return out

    top = pedestal.height + pedestal.post_height + pedestal.plate[1] + pedestal.cup_block[2]
    lo, hi = top - ball.radius, top + ball.radius  # touching at lo, clear at hi
    assert distance(np.array([0, 0, hi])) > ball.radius
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if distance(np.array([0.0, 0.0, mid])) < ball.radius:
            lo = mid
        else:
            hi = mid
    assert pedestal.ball_rest_z(ball.radius) == pytest.approx(hi, abs=1e-9)
    plate_top = pedestal.height + pedestal.post_height + pedestal.plate[1]
    assert hi - ball.radius > plate_top, "the ball rests on the cup, not the plate"
    outer = np.hypot(pedestal.cup_radius + pedestal.cup_block[0] / 2, pedestal.cup_block[1] / 2)
    assert outer < ball.radius
    with pytest.raises(ValueError, match="falls through"):
        pedestal.ball_rest_z(pedestal.cup_radius - pedestal.cup_block[0])


def test_where_a_ball_stops_the_fingers_is_predicted_by_the_jaw_geometry():
    """``Linkage.opening`` narrows monotonically over TALOS' stroke and ``position_for_width``
    inverts it; the 50 mm ball stops the simulated fingers (MuJoCo, 20 grasp-walk trials) at
    -0.336 to -0.354 rad, where the geometry predicts it; too wide or too narrow an object has no
    such position."""
    from marionette import robots
    from marionette.execution.factory import gripper_linkage
    from marionette.models.objects import Ball

    for side in ("left", "right"):
        g = robots.semantics("talos").gripper(f"talos/{side}_gripper")
        linkage = gripper_linkage("talos", g.name)
        lo, hi = g.closed_position, g.open_position
        widths = [linkage.opening(q) for q in np.linspace(hi, -0.55, 12)]
        assert all(a > b for a, b in zip(widths, widths[1:])), widths
        for w in (0.02, 0.043, 0.05, 0.08):
            q = linkage.position_for_width(w, lo, hi)
            assert lo <= q <= hi and linkage.opening(q) == pytest.approx(w, abs=1e-6)
        assert linkage.position_for_width(0.2, lo, hi) is None
        q_ball = linkage.position_for_width(2 * Ball().radius, lo, hi)
        assert -0.365 < q_ball < -0.325, (side, q_ball)


def test_fingers_stopped_away_from_where_the_object_stops_them_hold_something_else():
    from marionette.scenarios.standing_grasp import grasp_check

    for name, j in _bundled_gripper_joints():
        stroke = j.closed_position - j.open_position
        expected = j.open_position + 0.4 * stroke
        for off in (-0.05, 0.0, 0.05):
            assert grasp_check(j, expected + off * stroke, 0.1, expected, 0.1) is None, name
        for off in (-0.2, 0.2, 0.3):
            message = grasp_check(j, expected + off * stroke, 0.1, expected, 0.1)
            assert message is not None and "not the object" in message, name
