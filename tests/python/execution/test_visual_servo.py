"""Vision in the loop (thesis 000 §5.2.2-5.2.3): the correction's fixed point puts the object on
its plan whatever rigid bias lies between the reference and the object, the integrator
converges through camera noise and never moves faster than its limits, corrected references
keep their twists consistent (finite differences), corrected samples are re-sent when a
measurement arrives, and the gaze posture points the camera at its target (Pinocchio FK)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from marionette import lcmt_object_pose, lcmt_object_poses, robots
from marionette.execution.references import StepTrajectory
from marionette.execution.streamer import ReferenceStreamer
from marionette.execution.visual_servo import (
    ServoOptions,
    TaskCorrection,
    approach_fixed_point,
    correction_fixed_point,
    head_gaze_posture,
    left_multiply,
    right_multiply,
    step_toward,
)


def _random_pose(rng, scale_m: float = 0.5, scale_rad: float = 1.0) -> pin.SE3:
    return pin.exp6(np.concatenate([rng.normal(0, scale_m, 3), rng.normal(0, scale_rad, 3)]))


def _rows(poses: list[pin.SE3]) -> np.ndarray:
    out = []
    for X in poses:
        q = pin.Quaternion(X.rotation)
        out.append([*X.translation, q.w, q.x, q.y, q.z])
    return np.array(out)


def _pose(row: np.ndarray) -> pin.SE3:
    return pin.SE3(pin.Quaternion(row[3], row[4], row[5], row[6]).normalized().matrix(), row[:3])


def test_fixed_point_puts_the_object_on_its_plan_for_any_rigid_bias():
    rng = np.random.default_rng(0)
    for _ in range(20):
        P, X_GO, B, C = (_random_pose(rng) for _ in range(4))
        R = P * C  # the reference tracked when the image was taken
        O_measured = R * B  # what lies between reference and object: B, unknown
        C_star = correction_fixed_point(X_GO, O_measured, R)
        O_after = P * C_star * B  # the object once the new reference is tracked
        O_plan = P * X_GO
        assert np.allclose(O_after.homogeneous, O_plan.homogeneous, atol=1e-9)


def test_approach_fixed_point_moves_the_whole_approach_with_the_object():
    """§5.3.1, the grasp: the object lies off its plan by any rigid displacement. Streamed as
    L P(t) with L = P_e C* P_e^-1, every sample of the approach keeps the planned pose relative
    to the object where it is measured (so the last centimetres run along the measured handle's
    axis), and the goal is the planned grasp on the measured object."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        O_plan, D = _random_pose(rng), _random_pose(rng, 0.05, 0.17)
        O_measured = D * O_plan
        path = [O_plan * _random_pose(rng, 0.2, 0.5) for _ in range(5)]  # P(t), P_e = path[-1]
        P_e = path[-1]
        C_star = approach_fixed_point(P_e, O_measured, O_plan)
        L = P_e * C_star * P_e.inverse()
        for P in path:
            planned_rel = O_plan.inverse() * P
            corrected_rel = O_measured.inverse() * (L * P)
            assert np.allclose(corrected_rel.homogeneous, planned_rel.homogeneous, atol=1e-9)
        # A measurement of the plan itself corrects nothing.
        assert np.allclose(
            approach_fixed_point(P_e, O_plan, O_plan).homogeneous, np.eye(4), atol=1e-12
        )


def test_step_toward_respects_its_limits_and_reaches_the_target():
    rng = np.random.default_rng(1)
    C, target = _random_pose(rng, 0.05, 0.2), _random_pose(rng, 0.05, 0.2)
    nxt = step_toward(C, target, 0.5, 0.001, 0.002)
    xi = pin.log6(C.actInv(nxt)).vector
    assert np.linalg.norm(xi[:3]) <= 0.001 + 1e-12 and np.linalg.norm(xi[3:]) <= 0.002 + 1e-12
    # Along the geodesic to the target: the step is parallel to log(C^-1 C*).
    full = pin.log6(C.actInv(target)).vector
    assert abs(np.dot(xi, full) / (np.linalg.norm(xi) * np.linalg.norm(full)) - 1.0) < 1e-9
    assert np.allclose(
        step_toward(C, target, 1.0, 10.0, 10.0).homogeneous, target.homogeneous, atol=1e-12
    )


@pytest.mark.parametrize("multiply", [right_multiply, left_multiply])
def test_corrected_twists_match_finite_differences(multiply):
    rng = np.random.default_rng(2)
    C = _random_pose(rng, 0.1, 0.3)
    v, w = rng.normal(size=3), rng.normal(size=3)
    X0 = _random_pose(rng)
    dt = 1e-6
    # X(t): origin moving at v, axes turning at w (world), sampled at 0 and dt.
    Xs = [pin.SE3(pin.exp3(w * t) @ X0.rotation, X0.translation + v * t) for t in (0.0, dt)]
    values, derivs = multiply(_rows(Xs), np.array([[*v, *w]] * 2), C)
    a, b = _pose(values[0]), _pose(values[1])
    expected = X0 * C if multiply is right_multiply else C * X0
    assert np.allclose(a.homogeneous, expected.homogeneous, atol=1e-12)
    fd_v = (b.translation - a.translation) / dt
    fd_w = pin.log3(b.rotation @ a.rotation.T) / dt
    assert np.allclose(derivs[0, :3], fd_v, atol=1e-4)
    assert np.allclose(derivs[0, 3:], fd_w, atol=1e-4)


class _Plant:
    """The object held by a hand that tracks the reference exactly, with a rigid bias B."""

    def __init__(self) -> None:
        self.X_GO = pin.SE3(pin.exp3(np.array([0.0, math.pi / 2, 0.0])), np.array([0.0, 0.0, 0.1]))
        # The planned grasp, off by a slip of 1.4 cm / 6 deg (and sag, encoder offsets: one map).
        bias = pin.SE3(
            pin.exp3(np.radians(6.0) * np.array([0.3, 0.2, 0.93])), np.array([0.01, -0.008, 0.006])
        )
        self.B_true = self.X_GO * bias
        self.P = pin.SE3(pin.exp3(np.array([0.1, -0.2, 0.3])), np.array([0.4, 0.2, 0.9]))


def test_integrator_converges_through_camera_noise_within_its_speed_limit():
    """The servo loop of VisualServo.update on a plant O = R B (B: the grasp off by 1.4 cm,
    6 deg): measurements
    every 0.1 s with 2 mm / 0.5 deg noise; after 3 s the object is within 3 mm / 0.6 deg of its
    plan, and the correction never moved faster than max_speed."""
    from marionette.execution.visual_servo import VisualServo

    plant = _Plant()
    options = ServoOptions(
        alpha=0.3,
        max_speed=0.03,
        max_angular_speed=0.3,
        noise_position_m=0.002,
        noise_angle_rad=math.radians(0.5),
        seed=3,
    )

    class Bus:
        def subscribe(self, channel, type_, handler):
            self.handler = handler

    bus = Bus()
    servo = VisualServo(bus, [], [], None, {}, options)
    c = TaskCorrection(
        "left_gripper",
        True,
        pin.SE3.Identity(),
        False,
        10_000_000,
        0,
        pin.SE3.Identity(),
        [(0, pin.SE3.Identity())],
        frame="gripper_left_base_link",
    )
    servo._current = [(c, type("S", (), {"index": 0})(), "plank", plant.X_GO, False)]
    planned = {"left_gripper": (_rows([plant.P] * 4000), np.zeros((4000, 6)))}
    previous = c.C
    for k in range(1, 31):
        now = k * 100_000
        O = plant.P * c.active_at(now) * plant.B_true
        msg = lcmt_object_poses()
        pose = lcmt_object_pose()
        pose.utime, pose.object_name = now, "plank"
        q = pin.Quaternion(O.rotation)
        pose.position_world, pose.quaternion_world = list(O.translation), [q.w, q.x, q.y, q.z]
        pose.reprojection_error = 0.5
        msg.objects, msg.num_objects = [pose], 1
        bus.handler(msg)
        assert servo.update(planned, 1000, now)
        moved = pin.log6(previous.actInv(c.C)).vector
        assert np.linalg.norm(moved[:3]) <= options.max_speed * 0.1 + 1e-9
        previous = c.C
    O = plant.P * c.C * plant.B_true
    O_plan = plant.P * plant.X_GO
    assert np.linalg.norm(O.translation - O_plan.translation) < 0.003
    assert math.degrees(np.linalg.norm(pin.log3(O_plan.rotation.T @ O.rotation))) < 0.6
    assert servo.measurements_used == 30


def test_a_grasp_correction_is_streamed_on_the_left_and_blends_out_to_the_plan():
    """After a servoed grasp, the next step of that gripper streams L P(t) from the correction
    where it was (no jump at the switch) and ends on the plan P (blend_out), L = P_e C P_e^-1."""
    rng = np.random.default_rng(5)
    n = 400
    P = [pin.SE3(np.eye(3), np.array([0.5 + 0.001 * k, 0.0, 1.0])) for k in range(n)]
    anchor, C = _random_pose(rng), _random_pose(rng, 0.04, 0.1)
    c = TaskCorrection(
        "right_gripper", False, C, True, (n - 1) * 1000, 0, C, [(0, C)], frame="f", anchor=anchor
    )
    refs = {"right_gripper": (_rows(P), np.zeros((n, 6)))}
    sent = []
    s = ReferenceStreamer(
        sent.append, 3, refs, start_utime=0, chunk_samples=200, lookahead_s=1.0, corrections=[c]
    )
    for now in range(0, 1_000_000, 10_000):
        s.pump(now)
    rows = np.vstack([m.value for m in sent])
    L = anchor * C * anchor.inverse()
    assert np.allclose(_pose(rows[0]).homogeneous, (L * P[0]).homogeneous, atol=1e-9)
    assert np.allclose(_pose(rows[-1]).homogeneous, P[-1].homogeneous, atol=1e-9)


def test_corrected_samples_are_re_sent_from_now_when_a_measurement_arrives():
    n = 1500
    P = [pin.SE3(np.eye(3), np.array([0.001 * k, 0.0, 1.0])) for k in range(n)]
    refs = {
        "left_gripper": (_rows(P), np.zeros((n, 6))),
        "com": (np.zeros((n, 3)), np.zeros((n, 3))),
    }
    c = TaskCorrection(
        "left_gripper",
        True,
        pin.SE3.Identity(),
        False,
        n * 1000,
        0,
        pin.SE3.Identity(),
        [(0, pin.SE3.Identity())],
        frame="f",
    )

    class Servo:
        options = ServoOptions(lead_us=20_000, refresh_us=50_000)

        def update(self, planned, dt_us, now):
            if now == 300_000:  # a measurement: the correction moves 1 cm up
                c.C = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.01]))
                c.version += 1

    sent = []
    s = ReferenceStreamer(
        sent.append,
        3,
        refs,
        start_utime=0,
        chunk_samples=200,
        lookahead_s=1.0,
        corrections=[c],
        servo=Servo(),
    )
    for now in range(0, 2_000_000, 10_000):
        s.pump(now)
    grip = [m for m in sent if m.task_name == "left_gripper"]
    resent = [m for m in grip if m.utime == 320_000]
    assert len(resent) == 1  # from now + lead, the first measurement's effect
    # The stream the controller ends up with: later chunks replace the future from their start.
    stream = {}
    for m in grip:
        k0 = m.utime // 1000
        for k in [k for k in stream if k >= k0]:
            del stream[k]
        for i, row in enumerate(m.value):
            stream[k0 + i] = row
    z = np.array([stream[k][2] for k in range(n)])
    assert np.allclose(z[:320], 1.0) and np.allclose(z[320:], 1.01)
    assert grip[-1].last_chunk and max(stream) == n - 1
    # Uncorrected tasks are streamed once, untouched.
    assert sum(m.num_samples for m in sent if m.task_name == "com") == n


def test_gaze_posture_points_the_camera_at_the_target_with_the_head_only():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    frame = robots.robot("talos").camera_frame
    q = pin.neutral(model)
    q[2] = 1.02
    n = 101
    values = np.tile(q, (n, 1))
    traj = StepTrajectory(
        1e-3,
        0.1,
        np.arange(n) * 1e-3,
        values.copy(),
        values.copy(),
        {"posture": (values, np.zeros((n, model.nv)))},
    )
    # A point moving sideways 0.7 m ahead, 0.4 m below the camera: within the head's reach.
    targets = np.array([[0.7, -0.2 + 0.004 * k, 1.25] for k in range(n)])
    head_gaze_posture(model, traj, targets, frame, every=10)
    data = model.createData()
    head = {model.joints[model.getJointId(j)].idx_q for j in ("head_1_joint", "head_2_joint")}
    for k in (0, 37, 100):
        qk = traj.references["posture"][0][k]
        pin.framesForwardKinematics(model, data, qk)
        p_C = data.oMf[model.getFrameId(frame)].actInv(targets[k])
        assert p_C[2] > 0 and np.linalg.norm(p_C[:2] / p_C[2]) < 0.01  # on the optical axis
        changed = {i for i in range(model.nq) if abs(qk[i] - q[i]) > 1e-12}
        assert changed <= head
    # Head velocities: central differences of the rewritten positions.
    vals, ders = traj.references["posture"]
    j = model.joints[model.getJointId("head_2_joint")]
    assert ders[50, j.idx_v] == pytest.approx((vals[51, j.idx_q] - vals[49, j.idx_q]) / 2e-3)


def test_the_factory_servoes_the_first_grasp_and_the_placement(talos_plank):
    """Thesis 000 §5.3.1: PBVS on "the grabbing of the plank" and between pre-placement and
    placement. In the plank plan: the right gripper's approach to the pre-grasp of the plank on
    the table (the grasp then follows the plan, shifted), and the two steps that end in the
    placement waypoints (..._preplace, ..._intersec) while the left gripper holds the plank —
    not the right gripper lifting it off the table (intersec -> preplace), nor the left gripper's
    approach of the plank the right one holds (relative to it). Without vision (the factory's
    default) no task is pbvs."""
    import dataclasses

    from marionette.execution.factory import build_specs

    assert not any(t.kind == "pbvs" for spec in talos_plank.specs for t in spec.tasks)
    ctx = dataclasses.replace(talos_plank.ctx, visual_servoing=True)
    specs = build_specs(talos_plank.steps, ctx)
    servoed = {
        (s.index, t.name)
        for s, spec in zip(talos_plank.steps, specs)
        for t in spec.tasks
        if t.kind == "pbvs"
    }
    placement = {
        (s.index, "left_gripper")
        for s in talos_plank.steps
        if s.to_state.endswith(("_preplace", "_intersec"))
        and not s.from_state.endswith("_intersec")
        and "talos/left_gripper" in s.grasps
        and "talos/left_gripper" in s.grasps_to
    }
    grasp = {
        (s.index, "right_gripper")
        for s in talos_plank.steps
        if s.to_state.endswith("_pregrasp")
        and not s.grasps
        and not s.grasps_from
        and s.parent_grasps_to.get("talos/right_gripper") == "plank/H1"
    }
    assert len(placement) == 2 and len(grasp) == 1
    assert servoed == placement | grasp
    for _s, spec in zip(talos_plank.steps, specs):
        for t in spec.tasks:
            if t.kind == "pbvs":
                assert t.streamed and t.frame == talos_plank.ctx.gripper_frames[f"talos/{t.name}"]


@pytest.mark.slow
def test_the_gaze_keeps_the_plank_in_the_field_of_view_where_it_is_servoed(talos_plank):
    """Rendered check of the gaze (MuJoCo, the demo scene, the demo's detector settings): along
    the approach to the first grasp, at the end of the carry to the pre-placement and during the
    placement, with the head turned by the posture references, the plank's tags are detected in
    the head camera's image and the plank pose is within 5 mm / 1°."""
    import dataclasses

    import marionette
    from marionette._core import sim
    from marionette.execution.factory import build_specs
    from marionette.execution.references import compute_references, sample_step
    from marionette.execution.visual_servo import add_gaze
    from marionette.perception.camera import CameraIntrinsics
    from marionette.perception.detector import AprilTagDetector, DetectorConfig
    from marionette.perception.objects import estimate_body_pose, load_tagged_bodies, tag_sizes
    from marionette.scenarios import SCENARIOS

    p = talos_plank
    specs = build_specs(p.steps, dataclasses.replace(p.ctx, visual_servoing=True))
    servoed = [i for i, spec in enumerate(specs) if any(t.kind == "pbvs" for t in spec.tasks)]
    trajs = {}
    for s in p.steps[: servoed[-1] + 1]:
        trajs[s.index] = sample_step(s, p.robot_map, 1e-3, 0.5, 0.5)
        compute_references(trajs[s.index], specs[s.index], p.model)
    add_gaze(
        trajs, p.steps[: servoed[-1] + 1], p.robot_map, "plank", robots.robot("talos").camera_frame
    )
    scene = sim.MjScene(str(marionette.MODELS_DIR / "scenes" / "talos_plank.xml"))
    scene.reset_keyframe("reference")
    renderer = sim.RgbdRenderer(scene, "head_rgbd", 640, 480)
    k = renderer.intrinsics
    K = CameraIntrinsics(k.width, k.height, k.fx, k.fy, k.cx, k.cy)
    (plank,) = load_tagged_bodies([marionette.MODELS_DIR / "objects" / "plank.yaml"])
    detector = AprilTagDetector(
        DetectorConfig(
            tag_sizes=tag_sizes([plank]), quad_decimate=SCENARIOS["plank-flip"].quad_decimate
        )
    )
    pregrasp, carry, place = servoed
    first, grasp = pregrasp, pregrasp + 1  # the grasp follows the servoed pre-grasp
    views = (
        (first, 0.0),
        (pregrasp, 1.0),
        (grasp, 0.5),
        (grasp, 1.0),
        (carry, 1.0),
        (place, 0.0),
        (place, 1.0),
    )
    seen = 0
    for i, fraction in views:
        traj = trajs[i]
        n = int(fraction * (traj.num_samples - 1))
        q = traj.references["posture"][0][n]
        X_WO = p.robot_map.object_pose(traj.q_plan[n], "plank")
        qpos = scene.qpos.copy()
        n = robots.mujoco_nq("talos")  # the robot's block of qpos (its moving fingers included)
        qpos[:n] = robots.pinocchio_to_mujoco("talos", q)
        quat = pin.Quaternion(X_WO.rotation)
        qpos[n : n + 7] = [*X_WO.translation, quat.w, quat.x, quat.y, quat.z]
        scene.qpos = qpos
        scene.forward()
        rgb, depth = renderer.render(scene)
        gray = np.rint(rgb.mean(axis=2)).astype(np.uint8)
        detections = [d for d in detector.detect(gray, K, depth=depth) if plank.tag(d.tag_id)]
        if not detections:
            continue
        seen += 1
        X_WC = pin.SE3(renderer.camera_pose(scene))
        X_CB = estimate_body_pose(plank, detections, K, depth=depth).X_CB
        X_true = X_WC.inverse() * pin.SE3(scene.body_pose("plank"))
        assert np.linalg.norm(X_CB.translation - X_true.translation) < 5e-3
        assert math.degrees(np.linalg.norm(pin.log3(X_true.rotation.T @ X_CB.rotation))) < 1.0
    assert seen == len(views)


def _standing_step(model, q: np.ndarray, n: int) -> StepTrajectory:
    values = np.tile(q, (n, 1))
    return StepTrajectory(
        1e-3,
        (n - 1) * 1e-3,
        np.arange(n) * 1e-3,
        values.copy(),
        values.copy(),
        {"posture": (values, np.zeros((n, model.nv)))},
    )


def _plank_view(model, geom):
    from marionette.execution.visual_servo import ObjectView
    from marionette.perception.objects import tagged_bodies_from_semantics
    from marionette.perception.visibility import LineOfSight, ViewLimits

    camera = robots.robot("talos").cameras[0]
    (body,) = tagged_bodies_from_semantics(robots.load_object("plank").semantics)
    return ObjectView(
        model,
        camera.frame,
        body,
        camera.intrinsics(),
        LineOfSight(model, geom, None, camera.frame),
        (ViewLimits(margin_px=20.0, min_depth=0.2, max_depth=1.2, max_angle_deg=60.0),),
    )


@pytest.mark.parametrize("ahead_m", [0.38, 0.4, 0.43])
def test_the_gaze_leans_the_torso_only_as_far_as_the_tags_come_into_view(ahead_m):
    """The plank standing on the table 0.38-0.43 m before half-sitting TALOS is below the image
    at the head's pitch limit; the lean makes a tag visible (the kinematic prediction), starts and
    ends on the plan, moves nothing but the lean joint, and is the smallest that does (one
    increment less does not show it)."""
    from marionette.execution.visual_servo import aim_camera, lean_for_view

    model, geom = robots.load_pinocchio("talos", with_collision=True)
    q = robots.reference_configuration("talos", model)
    view = _plank_view(model, geom)
    X_WO = pin.XYZQUATToSE3(np.array([ahead_m, -0.02, 0.8316, 0.0, -0.7071068, 0.0, 0.7071068]))
    n = 401
    head = ("head_1_joint", "head_2_joint")
    hidx = [model.joints[model.getJointId(j)].idx_q for j in head]
    lean_q = model.joints[model.getJointId("torso_2_joint")].idx_q
    bounds = (model.lowerPositionLimit[hidx] + 0.03, model.upperPositionLimit[hidx] - 0.03)
    data = model.createData()

    def seen_with(lean: float) -> int:
        qk = q.copy()
        qk[lean_q] += lean
        aim_camera(model, data, view.fid, qk, hidx, bounds, [0, 1], X_WO.translation)
        return view.seen(qk, X_WO)

    assert seen_with(0.0) == 0  # the case: the head alone does not see it
    traj = _standing_step(model, q, n)
    targets = np.tile(X_WO.translation, (n, 1))
    lean = lean_for_view(traj, targets, [X_WO] * n, view, head, "torso_2_joint", samples=41)
    assert lean != 0.0
    assert seen_with(lean) >= 1 and seen_with(lean - 0.05 * np.sign(lean)) == 0
    values, derivs = traj.references["posture"]
    assert np.allclose(values[0], q) and np.allclose(values[-1], q)
    assert values[n // 2, lean_q] == pytest.approx(q[lean_q] + lean)
    changed = {i for i in range(model.nq) if np.any(np.abs(values[:, i] - q[i]) > 1e-12)}
    assert changed == {lean_q}
    v = model.joints[model.getJointId("torso_2_joint")].idx_v
    k = n // 5
    assert derivs[k, v] == pytest.approx((values[k + 1, lean_q] - values[k - 1, lean_q]) / 2e-3)


def test_the_gaze_does_not_lean_when_the_head_sees_the_object():
    from marionette.execution.visual_servo import lean_for_view

    model, geom = robots.load_pinocchio("talos", with_collision=True)
    q = robots.reference_configuration("talos", model)
    X_WO = pin.XYZQUATToSE3(np.array([0.6, -0.02, 0.8316, 0.0, -0.7071068, 0.0, 0.7071068]))
    traj = _standing_step(model, q, 201)
    before = traj.references["posture"][0].copy()
    lean = lean_for_view(
        traj,
        np.tile(X_WO.translation, (201, 1)),
        [X_WO] * 201,
        _plank_view(model, geom),
        ("head_1_joint", "head_2_joint"),
        "torso_2_joint",
    )
    assert lean == 0.0 and np.array_equal(traj.references["posture"][0], before)


def test_tags_in_view_against_a_pinhole_projection():
    """A tag straight ahead is seen; turned beyond the angle limit, pushed out of the image, or
    behind the camera it is not (projection written here: u = f x / z + c)."""
    from marionette.perception.camera import CameraIntrinsics
    from marionette.perception.objects import TaggedBody, TagOnBody
    from marionette.perception.visibility import ViewLimits, tags_in_view

    K = CameraIntrinsics.from_fovy(640, 480, 45.0)
    body = TaggedBody("b", "base_link", (TagOnBody(1, 0.05, pin.SE3.Identity()),))
    limits = ViewLimits(margin_px=20.0, min_depth=0.2, max_depth=1.2, max_angle_deg=60.0)
    facing = pin.SE3(pin.utils.rotate("y", math.pi), np.zeros(3))  # tag z towards the lens
    f = 0.5 * 480 / math.tan(math.radians(22.5))
    for x, z, turn_deg, expected in [
        (0.0, 0.5, 0.0, 1),
        (0.0, 0.5, 55.0, 1),
        (0.0, 0.5, 65.0, 0),
        (0.0, 1.5, 0.0, 0),  # beyond max_depth
        (-0.5, -0.5, 0.0, 0),  # behind the camera
    ]:
        X_CB = pin.SE3(pin.utils.rotate("x", math.radians(turn_deg)), np.array([x, 0.0, z]))
        assert tags_in_view(pin.SE3.Identity(), X_CB * facing, body, K, limits) == expected
    # The image edge: the centre's column u = f x / z + cx against the margin.
    for u_target, expected in [(640 - 21.0, 1), (640 - 19.0, 0), (21.0, 1), (19.0, 0)]:
        x = (u_target - K.cx) * 0.5 / f
        X_CB = pin.SE3(np.eye(3), np.array([x, 0.0, 0.5]))
        assert tags_in_view(pin.SE3.Identity(), X_CB * facing, body, K, limits) == expected


@pytest.mark.parametrize("seed", range(4))
def test_holding_the_tasks_above_the_posture_while_the_torso_leans(seed):
    """hold_tasks against forward kinematics: after a random torso lean from a random posture
    near half-sitting, the soles, the centre of mass (x, y), one gripper and the two grippers'
    relative pose are where they were (Pinocchio FK), and the leaned joint kept its value."""
    from marionette.control.spec import TaskSpec
    from marionette.execution.visual_servo import hold_tasks

    rng = np.random.default_rng(seed)
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    q_ref = robots.reference_configuration("talos", model)
    arms = [
        model.joints[model.getJointId(f"arm_{s}_{i}_joint")].idx_q
        for s in ("left", "right")
        for i in range(1, 8)
    ]
    q_ref[arms] += rng.uniform(-0.3, 0.3, len(arms))
    tasks = [
        TaskSpec("left_sole_link", "se3", 0, frame="left_sole_link"),
        TaskSpec("right_sole_link", "se3", 0, frame="right_sole_link"),
        TaskSpec("com", "com", 0, mask=(True, True, False)),
        TaskSpec("right_gripper", "se3", 1, frame="gripper_right_base_link"),
        TaskSpec(
            "hands",
            "relative_se3",
            1,
            frame="gripper_left_base_link",
            frame_b="gripper_right_base_link",
        ),
    ]
    data_ref = model.createData()
    pin.framesForwardKinematics(model, data_ref, q_ref)
    pin.centerOfMass(model, data_ref, q_ref, False)
    lean = model.joints[model.getJointId("torso_2_joint")]
    q = q_ref.copy()
    q[lean.idx_q] += rng.uniform(0.1, 0.3)
    head = [model.joints[model.getJointId(j)].idx_v for j in ("head_1_joint", "head_2_joint")]
    held = hold_tasks(model, model.createData(), data_ref, q, tasks, [*head, lean.idx_v], 12)
    assert held[lean.idx_q] == q[lean.idx_q]
    data = model.createData()
    pin.framesForwardKinematics(model, data, held)
    for frame in ("left_sole_link", "right_sole_link", "gripper_right_base_link"):
        f = model.getFrameId(frame)
        err = pin.log6(data_ref.oMf[f].actInv(data.oMf[f])).vector
        assert np.linalg.norm(err) < 1e-5, frame
    fl, fr = model.getFrameId("gripper_left_base_link"), model.getFrameId("gripper_right_base_link")
    rel = pin.log6(
        data_ref.oMf[fl].actInv(data_ref.oMf[fr]).actInv(data.oMf[fl].actInv(data.oMf[fr]))
    ).vector
    assert np.linalg.norm(rel) < 1e-5
    com = pin.centerOfMass(model, data, held)
    assert np.allclose(com[:2], data_ref.com[0][:2], atol=1e-6)
