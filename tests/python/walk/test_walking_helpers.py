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
    direction, the same for the same seed, and over many seeds every quadrant and both ends of the
    range are drawn."""
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


def test_a_walk_that_looks_at_a_point_moves_only_the_head_for_it():
    """``walking_spec(gaze=...)``: every 1-DoF joint but the head's and the legs' held at level 1
    (the legs are the joints the feet hang from, by Pinocchio's supports), the streamed gaze on
    the camera frame at level 2, the whole posture below; a pitch and a gaze at once refused."""
    import pinocchio as pin

    from marionette import robots
    from marionette.execution.walking import walking_spec

    desc = robots.robot("talos")
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    spec = walking_spec("talos", 1, gaze=(1.3, -0.1, 0.8))
    tasks = {t.name: t for t in spec.tasks}
    legs = set()
    for foot in desc.feet:
        data = model.createData()
        q = pin.neutral(model)
        pin.framesForwardKinematics(model, data, q)
        for j in range(1, model.njoints):  # a joint is a leg's when moving it moves the sole
            dq = np.zeros(model.nv)
            if model.joints[j].nv != 1:
                continue
            dq[model.joints[j].idx_v] = 0.1
            moved = model.createData()
            pin.framesForwardKinematics(model, moved, pin.integrate(model, q, dq))
            frame = model.getFrameId(foot.frame)
            if not moved.oMf[frame].isApprox(data.oMf[frame], 1e-9):
                legs.add(model.names[j])
    one_dof = {model.names[j] for j in range(1, model.njoints) if model.joints[j].nv == 1}
    upper = tasks["upper_body"]
    assert upper.priority == 1 and upper.kind == "posture"
    assert set(upper.joints) == one_dof - legs - set(desc.calibration_head_joints)
    assert len(legs) == 12
    gaze = tasks["gaze"]
    assert (gaze.kind, gaze.priority, gaze.frame, gaze.streamed) == (
        "gaze",
        2,
        desc.camera_frame,
        True,
    )
    assert gaze.reference == (1.3, -0.1, 0.8)
    assert tasks["posture"].priority == 3 and not tasks["posture"].joints
    spec.to_lcm(0)
    with pytest.raises(ValueError, match="not both"):
        walking_spec("talos", 1, head_pitch=0.5, gaze=(1.0, 0.0, 0.8))


@pytest.mark.parametrize("target", [(1.3, -0.1, 0.8), (0.9, 0.3, 1.0), (2.0, -0.4, 1.0)])
def test_the_head_is_aimed_so_the_point_is_at_the_image_centre(target):
    """``aim_head``: with the head joints it returns, the point projects on the optical axis (a
    separate forward kinematics in the test); a point no head posture centres (straight below the
    feet) leaves a joint on its limit."""
    import pinocchio as pin

    from marionette import robots
    from marionette.scenarios.walking_scenario import aim_head

    desc = robots.robot("talos")
    model, _ = robots.load_pinocchio("talos", with_collision=False)

    def camera_point(head: dict[str, float], p) -> np.ndarray:
        q = robots.reference_configuration("talos", model)
        for name, value in head.items():
            q[model.joints[model.getJointId(name)].idx_q] = value
        data = model.createData()
        pin.framesForwardKinematics(model, data, q)
        return data.oMf[model.getFrameId(desc.camera_frame)].actInv(np.asarray(p, dtype=float))

    head = aim_head("talos", np.array(target))
    p = camera_point(head, target)
    assert p[2] > 0 and np.hypot(p[0], p[1]) / p[2] < 1e-6
    below = aim_head("talos", np.array([0.0, 0.0, 0.0]))
    limits = [
        (model.lowerPositionLimit[i], model.upperPositionLimit[i])
        for i in (model.joints[model.getJointId(j)].idx_q for j in desc.calibration_head_joints)
    ]
    assert any(min(abs(v - lo), abs(v - hi)) < 1e-6 for v, (lo, hi) in zip(below.values(), limits))


def test_the_gaze_follows_each_estimate_by_a_ramp_the_stream_then_holds():
    """``GazeFollower``: each estimate sends one chunk for the walking controller's gaze task:
    from the last target to the object's point, linear over the ramp, on the 1 ms grid after the
    controller's time, the stream's last (it holds its end), numbered in order."""
    import pinocchio as pin

    from marionette.scenarios.walking_scenario import GazeFollower

    class Client:
        def __init__(self):
            self.sent, self.now = [], 1_234_567

        def utime(self):
            return self.now

        def send_reference(self, chunk):
            self.sent.append(chunk)

    client = Client()
    point = np.array([0.0, 0.0, 0.8])
    start = pin.SE3(np.eye(3), np.array([1.3, -0.1, 0.0]))  # the gaze starts at [1.3, -0.1, 0.8]
    follower = GazeFollower(client, 1, point, start, ramp_s=0.2)
    X = pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, 0.4), np.array([1.1, -0.3, 0.0]))
    follower.follow(X)
    client.now += 200_000
    follower.follow(X)
    first, second = client.sent
    for k, c in enumerate(client.sent):
        assert (c.controller_id, c.task_name, c.last_chunk, c.sequence) == (1, "gaze", True, k)
        assert c.utime % 1000 == 0 and c.dt_us == 1000
    assert first.utime == 1_235_000 and first.num_samples == 200
    values = np.array(first.value)
    assert np.allclose(values[0], [1.3, -0.1, 0.8]) and np.allclose(values[-1], X.act(point))
    assert np.allclose(np.diff(values, axis=0), (values[-1] - values[0]) / 199)
    derivatives = np.array(first.derivative)
    assert np.allclose(derivatives[:-1], np.diff(values, axis=0) / 1e-3), "feed-forward = slope"
    assert np.allclose(np.array(second.value), X.act(point)), "the same estimate: it stays"


def test_the_grasp_acts_on_an_object_seen_at_rest_and_the_head_looks_for_one_last_seen_moving():
    """``look_for``: two consecutive estimates within 1 cm are the object at rest (no search);
    an object last seen moving (4 cm between frames: 0.2 m/s at 5 Hz) sends the head to each
    search point in turn until estimates made from then on show it at rest; never seen at rest,
    it returns None after every point. ``search_points``: the point, then rings around it."""
    from types import SimpleNamespace

    import pinocchio as pin

    from marionette.scenarios.walking_scenario import (
        GazeFollower,
        SlidingFixture,
        look_for,
        search_points,
    )

    class Client:
        def __init__(self):
            self.sent, self.now, self.on_tick = [], 1_000_000, None

        def utime(self):
            return self.now

        def send_reference(self, chunk):
            self.sent.append(chunk)

        def wait_time(self, seconds):
            self.now += round(seconds * 1e6)
            if self.on_tick is not None:
                self.on_tick(self)

    def estimate(fixture, client, x):
        obj = SimpleNamespace(
            object_name="pedestal", position_world=[x, -0.1, 0.0], quaternion_world=[1, 0, 0, 0]
        )
        fixture._on_poses(SimpleNamespace(utime=client.now, objects=[obj]))

    def setup(positions):
        client = Client()
        fixture = SlidingFixture(
            client, "pedestal", lambda p: pin.SE3.Identity(), lambda X: X.translation.copy()
        )
        gaze = GazeFollower(client, 1, np.zeros(3), pin.SE3.Identity())
        for x in positions:
            estimate(fixture, client, x)
            client.now += 200_000
        return client, fixture, gaze

    points = search_points(np.array([1.0, -0.1, 0.8]), radii=(0.15, 0.3), directions=8)
    assert len(points) == 17 and np.allclose(points[0], [1.0, -0.1, 0.8])
    rings = np.linalg.norm(np.array(points[1:]) - points[0], axis=1)
    assert np.allclose(rings, [0.15] * 8 + [0.3] * 8)
    assert np.allclose(np.array(points)[:, 2], 0.8), "searched at the object's height"

    client, fixture, gaze = setup([1.10, 1.06, 1.02, 1.017])
    X, looked = look_for(client, fixture, gaze, points, dwell_s=1.0)
    assert looked == 0 and X is not None and np.isclose(X.translation[0], 1.017)
    assert client.sent == [], "seen at rest: the head is not moved"

    client, fixture, gaze = setup([1.10, 1.06, 1.02])  # last seen moving
    start = client.now

    def found_at_third_point(c):
        if c.now - start > 2_300_000 and len(fixture.history) < 5:
            estimate(fixture, c, 1.0)
            c.now += 200_000
            estimate(fixture, c, 1.003)

    client.on_tick = found_at_third_point
    X, looked = look_for(client, fixture, gaze, points, dwell_s=1.0)
    assert looked == 3 and X is not None and np.isclose(X.translation[0], 1.003)
    # the head went to points 0, 1, 2, then followed the two estimates
    targets = [np.array(c.value)[-1] for c in client.sent]
    assert all(np.allclose(t, p) for t, p in zip(targets[:3], points[:3]))

    client, fixture, gaze = setup([1.10, 1.06])
    X, looked = look_for(client, fixture, gaze, points[:4], dwell_s=0.5)
    assert X is None and looked == 4 and len(client.sent) == 4
