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
    handover_fixed_point,
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


def test_handover_fixed_point_puts_the_approaching_gripper_where_the_plan_has_it_on_the_object():
    """§5.3.1, the hand-over: the object is anywhere in the holding hand the controller commands
    (H_c: the real hand sags below it, the grasp slipped: one unknown map B). Streamed relative
    to H as D* X_HG(t), every sample of the approach keeps the planned pose relative to the
    measured object, whatever B, H_c and the planned grasps."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        H_c, X_HO, B = _random_pose(rng), _random_pose(rng, 0.1), _random_pose(rng, 0.1, 0.5)
        O_m = H_c * B
        D = handover_fixed_point(X_HO, O_m, H_c)
        for X_HG in (_random_pose(rng, 0.3) for _ in range(3)):
            G = H_c * D * X_HG  # the approaching gripper once its relative reference is tracked
            planned = X_HO.inverse() * X_HG  # gripper relative to the object, as planned
            assert np.allclose((O_m.inverse() * G).homogeneous, planned.homogeneous, atol=1e-9)


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


def _pose_message(utime: int, obj: str, X: pin.SE3, reprojection_px: float = 0.5):
    """An OBJECT_POSES message with ``obj`` seen at ``X`` at image time ``utime``."""
    msg = lcmt_object_poses()
    pose = lcmt_object_pose()
    pose.utime, pose.object_name = utime, obj
    q = pin.Quaternion(X.rotation)
    pose.position_world, pose.quaternion_world = list(X.translation), [q.w, q.x, q.y, q.z]
    pose.reprojection_error = reprojection_px
    msg.objects, msg.num_objects = [pose], 1
    return msg


class _Bus:
    """The servo's LCM subscriptions, by channel; ``send`` delivers an object pose."""

    def __init__(self) -> None:
        self.handlers = {}

    def subscribe(self, channel, type_, handler):
        self.handlers[channel] = handler

    def send(self, utime: int, obj: str, X: pin.SE3, reprojection_px: float = 0.5) -> None:
        self.handlers["OBJECT_POSES"](_pose_message(utime, obj, X, reprojection_px))


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

    bus = _Bus()
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
        bus.send(now, "plank", plant.P * c.active_at(now) * plant.B_true)
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


def _servoed_line(n: int, measured_at_us: int):
    """A left-gripper reference along x (n samples), its servoed correction (identity) and a servo
    whose one measurement, at ``measured_at_us``, moves the correction 1 cm up."""
    P = [pin.SE3(np.eye(3), np.array([0.001 * k, 0.0, 1.0])) for k in range(n)]
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
            if now == measured_at_us:
                c.C = pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.01]))
                c.version += 1

    return (_rows(P), np.zeros((n, 6))), c, Servo()


def test_corrected_samples_are_re_sent_from_now_when_a_measurement_arrives():
    n = 1500
    grip, c, servo = _servoed_line(n, 300_000)
    refs = {"left_gripper": grip, "com": (np.zeros((n, 3)), np.zeros((n, 3)))}
    sent = []
    s = ReferenceStreamer(
        sent.append,
        3,
        refs,
        start_utime=0,
        chunk_samples=200,
        lookahead_s=1.0,
        corrections=[c],
        servo=servo,
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


def test_a_re_sent_stretch_is_made_whole_before_its_first_piece_is_sent():
    """A chunk replaces its stream's future from its start, so the first piece of a re-sent
    stretch cuts the controller's stream at its own end until the next piece comes: every piece
    is made before any is sent, and nothing slow (the corrected samples) comes between two."""
    grip, c, servo = _servoed_line(6000, 1_000_000)
    events: list[tuple[str, int]] = []
    s = ReferenceStreamer(
        lambda m: events.append(("sent", m.utime)),
        3,
        {"left_gripper": grip},
        start_utime=0,
        chunk_samples=200,
        lookahead_s=4.0,
        corrections=[c],
        servo=servo,
    )
    corrected = s._corrected

    def recorded(task, k0, k1):
        events.append(("made", k0))
        return corrected(task, k0, k1)

    s._corrected = recorded
    for now in range(0, 1_000_001, 10_000):
        s.pump(now)
    refresh = events[next(i for i, e in enumerate(events) if e == ("made", 1020)) :]
    pieces = [k for what, k in refresh if what == "sent"]
    assert pieces[0] == 1_020_000 and len(pieces) >= 3  # 1.02 s to the 4 s look-ahead
    assert [what for what, _ in refresh] == ["made"] * len(pieces) + ["sent"] * len(pieces)


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
    joints = robots.robot("talos").calibration_head_joints
    head_gaze_posture(model, traj, targets, frame, joints, every=10)
    data = model.createData()
    head = {model.joints[model.getJointId(j)].idx_q for j in joints}
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
    # A plan may reach a waypoint, leave it and come back (seed 4: the first pre-grasp and the
    # pre-placement twice): every such step is servoed. The last two placement steps end in the
    # pre-placement and the placement.
    assert grasp and len(placement) >= 2
    last, before = sorted(placement)[-1][0], sorted(placement)[-2][0]
    assert talos_plank.steps[last].to_state.endswith("_intersec")
    assert talos_plank.steps[before].to_state.endswith("_preplace")
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
    talos = robots.robot("talos")
    add_gaze(
        trajs,
        p.steps[: servoed[-1] + 1],
        p.robot_map,
        "plank",
        talos.camera_frame,
        talos.calibration_head_joints,
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
    # The servoed approach the grasp follows (a plan may reach the pre-grasp twice), and the
    # carry to the pre-placement and the placement (the last two servoed steps).
    pregrasp = next(i for i in servoed if p.steps[i + 1].kind == "grasp")
    carry, place = servoed[-2], servoed[-1]
    first, grasp = pregrasp, pregrasp + 1
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


def _visual(planned):
    import dataclasses

    from marionette.execution.factory import build_specs

    return build_specs(planned.steps, dataclasses.replace(planned.ctx, visual_servoing=True))


def test_the_carry_to_a_servoed_placement_is_servoed_under_the_same_grasp(talos_plank):
    """The object's error in the hand is one of the grasp: every pbvs task is servoed, and so is
    a gripper task in every step of the grasp that carries the object to a servoed placement —
    the whole last carry of the plank, its first step included (where the slip happens) — and
    nothing else: the right gripper's carry to the hand-over leads to no servoed placement."""
    from marionette.execution.visual_servo import handover_approaches, servoed_tasks
    from marionette.scenarios.plan_and_execute import last_carry_step

    steps, specs = talos_plank.steps, _visual(talos_plank)
    servoed = servoed_tasks(steps, specs, handovers=True)
    welded = servoed_tasks(steps, specs)  # hand-overs servoed with friction grasps only
    for step, spec in zip(steps, specs):
        names = servoed.get(step.index, set())
        assert {t.name for t in spec.tasks if t.kind == "pbvs"} <= names
        assert set(handover_approaches(step, spec)) <= names
        assert welded.get(step.index, set()) == names - set(handover_approaches(step, spec))
        pbvs = {t.name for t in spec.tasks if t.kind == "pbvs"}
        for name in names - pbvs - set(handover_approaches(step, spec)):
            gripper = f"talos/{name}"
            handle = step.grasps[gripper]  # it holds the object all along the step
            later = [(s, sp) for s, sp in zip(steps[step.index + 1 :], specs[step.index + 1 :])]
            run = []
            for s, sp in later:
                if s.grasps.get(gripper) != handle:
                    break
                run.append(sp)
            assert any(t.kind == "pbvs" and t.name == name for sp in run for t in sp.tasks)
    carry = last_carry_step(steps, "plank")
    assert "left_gripper" in servoed[carry]
    first_pbvs_of_left = min(
        i for i, names in servoed.items() if "left_gripper" in names and i > carry
    )
    assert all("left_gripper" in servoed[i] for i in range(carry, first_pbvs_of_left))
    right_carry = [s.index for s in steps if "talos/right_gripper" in s.grasps]
    assert right_carry and not any("right_gripper" in servoed.get(i, ()) for i in right_carry)


def _servo_on(planned, indices, options=None):
    from marionette.execution.references import compute_references, sample_step
    from marionette.execution.visual_servo import VisualServo

    specs = _visual(planned)
    trajs = {}
    for i in indices:
        trajs[i] = sample_step(planned.steps[i], planned.robot_map, 1e-3, 0.5, 0.5)
        compute_references(trajs[i], specs[i], planned.model)
    bus = _Bus()
    servo = VisualServo(
        bus, planned.steps, specs, planned.robot_map, trajs, options or ServoOptions()
    )
    return servo, bus, specs, trajs


def test_an_approach_starts_from_what_the_camera_saw_of_the_object_at_rest(talos_plank):
    """The step before the servoed approach to the plank on the table sees the plank displaced
    (4 cm, 8 deg) and the approach sees nothing (the reaching hand hides it): the approach's
    correction still reaches the fixed point of what was seen at rest by ``approach_settle`` of
    the step, never faster than ``max_approach_speed``. What was seen while a gripper touched the
    object is history: after such a step nothing is kept."""
    from marionette.execution.visual_servo import looks_before_approach

    p = talos_plank
    approach = next(  # the servoed approach the grasp follows
        s.index
        for s, spec in zip(p.steps, _visual(p))
        if any(t.kind == "pbvs" for t in spec.tasks)
        and not s.grasps
        and p.steps[s.index + 1].kind == "grasp"
    )
    look = approach - 1
    touching = next(s.index for s in p.steps if s.grasps)
    servo, bus, specs, trajs = _servo_on(p, [look, approach, touching])
    assert look in looks_before_approach(p.steps, specs)
    o = servo.options
    D = pin.SE3(pin.exp3(np.radians(8.0) * np.array([0.0, 0.0, 1.0])), np.array([0.03, -0.02, 0.0]))
    X_plan = p.robot_map.object_pose(trajs[approach].q_plan[0], "plank")
    seen = D * X_plan
    servo.begin_step(p.steps[look], specs[look], 0, 1000)
    for k in range(10):  # no update in between: the look step has nothing to correct
        bus.send(100_000 * (k + 1), "plank", seen)
    start = 2_000_000
    (c,) = servo.begin_step(p.steps[approach], specs[approach], start, 1000)
    assert c.servoed and c.anchor is not None
    expected = approach_fixed_point(c.anchor, seen, X_plan)
    settle = start + int(o.approach_settle * c.duration_us)
    previous, now = c.C, start
    while now <= settle:
        servo.update(trajs[approach].references, 1000, now)
        moved = pin.log6(previous.actInv(c.C)).vector
        assert np.linalg.norm(moved[:3]) <= o.max_approach_speed * 1e-3 + 1e-9
        assert np.linalg.norm(moved[3:]) <= o.max_approach_angular_speed * 1e-3 + 1e-9
        previous, now = c.C, now + 1000
    assert np.allclose(c.C.homogeneous, expected.homogeneous, atol=1e-6)
    assert np.linalg.norm(expected.translation) > 0.03  # a correction the usual pace would miss
    assert all(row["at_rest"] for row in servo.trace)

    # A step where a gripper holds the plank drops what was seen at rest.
    servo.begin_step(p.steps[touching], specs[touching], 3 * start, 1000)
    bus.send(3 * start + 10_000, "plank", seen)
    servo.update(trajs[touching].references, 1000, 3 * start + 20_000)
    (c,) = servo.begin_step(p.steps[approach], specs[approach], 4 * start, 1000)
    servo.update(trajs[approach].references, 1000, 4 * start + 500_000)
    assert c.C.isIdentity() and c.target is None


def test_a_carry_blends_a_grasps_correction_out_until_the_camera_measures_the_object(talos_plank):
    """After the hand-over, the left hand's carry starts from the correction its grasp left on
    (a left correction, which moved the hand with the object where it lay): without a
    measurement it blends out to the plan as after any grasp; at the first measurement it stays
    where the ramp had streamed it and then goes to the fixed point of that measurement."""
    from marionette.scenarios.plan_and_execute import last_carry_step

    p = talos_plank
    carry = last_carry_step(p.steps, "plank")
    servo, bus, specs, trajs = _servo_on(p, [carry])
    frame = p.ctx.gripper_frames["talos/left_gripper"]
    anchor = pin.SE3(np.eye(3), np.array([0.4, 0.3, 0.9]))
    C_grasp = pin.SE3(pin.exp3(np.array([0.0, 0.05, 0.0])), np.array([0.01, 0.0, -0.01]))
    for measured in (False, True):
        servo._carried[frame] = (C_grasp, anchor)
        corrections = servo.begin_step(p.steps[carry], specs[carry], 0, 1000)
        (c,) = [c for c in corrections if c.frame == frame]
        assert c.servoed and c.blend_out and c.anchor is None
        n = trajs[carry].num_samples
        P0 = _pose(trajs[carry].references[c.task][0][0])
        # no jump at the start: P0 C0 = L P0
        L = anchor * C_grasp * anchor.inverse()
        assert np.allclose((P0 * c.at_sample(0, 1000)).homogeneous, (L * P0).homogeneous)
        assert c.at_sample(n - 1, 1000).isIdentity(1e-9)
        if not measured:
            servo.end_step(corrections)
            assert servo._carried[frame][0].isIdentity()
            continue
        half = (n // 2) * 1000
        k = half // 1000
        P = _pose(trajs[carry].references[c.task][0][k])
        X_GO = servo._planned_grasp(trajs[carry], frame, "plank")
        slipped = P * c.at_sample(k, 1000) * X_GO * pin.SE3(np.eye(3), np.array([0.0, 0.008, 0.0]))
        ramp_there = c.at_sample((half + servo.options.lead_us) // 1000, 1000)
        expected = correction_fixed_point(X_GO, slipped, P * c.at_sample(k, 1000))
        bus.send(half, "plank", slipped)
        servo.update(trajs[carry].references, 1000, half)
        assert not c.blend_out
        assert np.allclose(c.C.homogeneous, ramp_there.homogeneous, atol=1e-6)
        for now in range(half, half + 3_000_000, 10_000):
            servo.update(trajs[carry].references, 1000, now)
        # the grasp's correction was no measurement of the object in the hand: the first one
        # is taken whole
        assert np.allclose(c.C.homogeneous, expected.homogeneous, atol=1e-9)


def _stuck_hand_servo(encoders: bool, lag_m: float = 0.0):
    """The integrator test's plant with a hand that stays on the plan P whatever the
    correction asks (a joint at its limit: the controller commands P), 30 s of measurements at
    10 Hz; ``encoders``: the servo has the robot's state and command (the hand measured
    ``lag_m`` from the commanded one), else it reads the reference. Returns (C at the end, the
    first measurement's fixed point, measurements not used)."""
    from marionette.execution.visual_servo import VisualServo

    plant = _Plant()

    bus = _Bus()
    servo = VisualServo(bus, [], [], None, {}, ServoOptions(max_tracking_m=0.02))
    if encoders:

        class States:
            def has_state(self):
                return True

        servo._states = States()
        lag = pin.SE3(np.eye(3), np.array([lag_m, 0.0, 0.0]))
        servo._hand_poses = lambda frame, utime: (plant.P * lag, plant.P)
    c = TaskCorrection("left_gripper", True, pin.SE3.Identity(), False, 60_000_000, 0, frame="f")
    c.history = [(0, pin.SE3.Identity())]
    servo._current = [(c, type("S", (), {"index": 0})(), "plank", plant.X_GO, False)]
    planned = {"left_gripper": (_rows([plant.P] * 60_000), np.zeros((60_000, 6)))}
    # the object off in the hand by a translation, where it goes with the (stuck) hand
    O = plant.P * plant.X_GO * pin.SE3(np.eye(3), np.array([0.01, -0.008, 0.006]))
    for k in range(1, 301):
        now = k * 100_000
        bus.send(now, "plank", O)
        servo.update(planned, 1000, now)
    first = correction_fixed_point(plant.X_GO, O, plant.P)
    return c.C, first, servo.measurements_hand_off_command


def test_a_hand_that_does_not_follow_its_correction_does_not_wind_it_up():
    """Read against the reference, the fixed point C* = X_GO O^-1 P C of a hand that does not
    move grows with C at every measurement: the correction winds up far past the first fixed
    point. Read against the hand the controller commands (which stays at P), it stays at that
    fixed point. A hand the encoders put 3 cm from the commanded one (lagging a fast carry)
    tells nothing: those measurements are not used."""
    C, first, _ = _stuck_hand_servo(encoders=False)
    assert np.linalg.norm(C.translation) > 3 * np.linalg.norm(first.translation)
    C, first, skipped = _stuck_hand_servo(encoders=True)
    assert skipped == 0
    assert np.allclose(C.homogeneous, first.homogeneous, atol=1e-9)
    C, first, skipped = _stuck_hand_servo(encoders=True, lag_m=0.03)
    assert skipped == 300 and C.isIdentity()


def test_the_hand_measured_and_commanded_at_an_image_time_against_forward_kinematics(talos_plank):
    """The servo's hand poses from the controller's ROBOT_STATE (measured joints, the base) and
    ROBOT_COMMAND (commanded joints) nearest an image's time: Pinocchio's forward kinematics of
    the gripper frame at those configurations, the commanded one on the measured base; none when
    the nearest message is more than 20 ms away."""
    from marionette import lcmt_robot_command, lcmt_robot_state

    p = talos_plank
    servo, bus, _, _ = _servo_on(p, [])
    model = p.model
    rng = np.random.default_rng(2)
    names = [model.names[j] for j in range(1, model.njoints) if model.joints[j].nq == 1]
    idx = [model.joints[model.getJointId(n)].idx_q for n in names]
    frame = p.ctx.gripper_frames["talos/left_gripper"]
    fid = model.getFrameId(frame)
    data = model.createData()
    for utime in (1_000_000, 1_010_000, 1_020_000):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        q_cmd = q.copy()
        q_cmd[idx] += rng.normal(0, 0.05, len(idx))
        state, command = lcmt_robot_state(), lcmt_robot_command()
        state.utime = command.utime = utime
        state.num_joints = command.num_joints = len(names)
        state.joint_name = command.joint_name = names
        state.joint_position = [float(q[i]) for i in idx]
        state.joint_velocity = state.joint_effort = [0.0] * len(names)
        command.joint_position = [float(q_cmd[i]) for i in idx]
        command.joint_velocity = [0.0] * len(names)
        state.base_position = list(q[:3])
        state.base_quaternion = [q[6], q[3], q[4], q[5]]
        bus.handlers["ROBOT_STATE"](state)
        bus.handlers["ROBOT_COMMAND"](command)
    measured, commanded = servo._hand_poses(frame, 1_021_000)
    pin.framesForwardKinematics(model, data, q)
    assert np.allclose(measured.homogeneous, data.oMf[fid].homogeneous, atol=1e-12)
    pin.framesForwardKinematics(model, data, q_cmd)
    assert np.allclose(commanded.homogeneous, data.oMf[fid].homogeneous, atol=1e-12)
    assert servo._hand_poses(frame, 1_050_000) is None


def test_the_hand_over_is_servoed_on_the_object_in_the_holding_hand(talos_plank):
    """The left gripper's approach to the plank the right one holds is servoed (its task is
    relative to the right gripper): the plank seen off in the right hand (a sagging wrist, a
    slip) moves the approach with it, D* reached by ``approach_settle`` of the step; the grasp
    that follows keeps D (the plan resumed, shifted), and once the left hand holds the plank
    alone its absolute task starts where the relative one ended: no jump."""
    from marionette.execution.visual_servo import handover_approaches

    p = talos_plank
    specs = _visual(p)
    handovers = [(s.index, handover_approaches(s, spec)) for s, spec in zip(p.steps, specs)]
    handovers = [(i, h) for i, h in handovers if h]
    assert handovers, "the plank plan hands the plank over"
    right = p.ctx.gripper_frames["talos/right_gripper"]
    assert all(h == {"left_gripper": right} for _, h in handovers)
    approach = handovers[-1][0]
    grasp = approach + 1
    alone = next(s.index for s in p.steps[grasp:] if "talos/right_gripper" not in s.grasps)
    assert p.steps[grasp].grasps_to.get("talos/left_gripper") == "plank/H8"
    servo, bus, specs, trajs = _servo_on(p, [approach, grasp, alone], ServoOptions(handovers=True))
    o = servo.options

    start = 1_000_000
    (c,) = [
        c for c in servo.begin_step(p.steps[approach], specs[approach], start, 1000) if c.holder
    ]
    assert c.servoed and c.holder == right and c.anchor is None and c.task == "left_gripper"
    # without robot states the holding hand is its planned pose at the image time
    B = pin.SE3(
        pin.exp3(np.radians(6.0) * np.array([0.2, 1.0, 0.1])), np.array([0.0, -0.04, -0.05])
    )
    traj = trajs[approach]
    X_HO = servo._planned_grasp(traj, right, "plank")
    expected = None
    previous = c.C
    for now in range(start, start + 2_000_000, 1000):
        if (now - start) % 33_000 == 0:
            k = min((now - start) // 1000, traj.num_samples - 1)
            H = servo._planned_pose(traj, right, k)
            seen = H * X_HO * B  # the plank off by B in the right hand
            expected = handover_fixed_point(X_HO, seen, H)
            bus.send(now, "plank", seen)
        servo.update(traj.references, 1000, now)
        moved = pin.log6(previous.actInv(c.C)).vector
        assert np.linalg.norm(moved[:3]) <= o.max_approach_speed * 1e-3 + 1e-9
        assert np.linalg.norm(moved[3:]) <= o.max_approach_angular_speed * 1e-3 + 1e-9
        previous = c.C
    assert np.allclose(expected.homogeneous, (X_HO * B * X_HO.inverse()).homogeneous, atol=1e-9)
    assert np.allclose(c.C.homogeneous, expected.homogeneous, atol=1e-6)
    # streamed: the left gripper relative to the right, corrected on the left in its frame
    values, derivatives = traj.references[c.task]
    corrected, _ = c.apply(values[-1:], derivatives[-1:], c.C)
    assert np.allclose(_pose(corrected[0]).homogeneous, (c.C * _pose(values[-1])).homogeneous)
    servo.end_step([c])

    (g,) = [c for c in servo.begin_step(p.steps[grasp], specs[grasp], 2 * start, 1000) if c.holder]
    assert not g.servoed and not g.blend_out
    assert np.allclose(g.C.homogeneous, c.C.homogeneous, atol=1e-9)
    servo.end_step([g])
    H_end = servo._planned_end(trajs[grasp], right)
    X_HG_end = _pose(trajs[grasp].references["left_gripper"][0][-1])
    world_end = H_end * g.C * X_HG_end

    corrections = servo.begin_step(p.steps[alone], specs[alone], 3 * start, 1000)
    (a,) = [c for c in corrections if c.task == "left_gripper"]
    assert not a.holder
    P0 = _pose(trajs[alone].references["left_gripper"][0][0])
    world_start, _ = a.apply(_rows([P0]), np.zeros((1, 6)), a.at_sample(0, 1000))
    assert np.allclose(_pose(world_start[0]).homogeneous, world_end.homogeneous, atol=1e-6)


def test_the_torso_leans_where_the_servo_looks_but_not_for_a_hand_over_alone(talos_plank):
    """The gaze leans the torso on the servoed steps and before an approach to an object at
    rest, never on a step whose only servoed task is a hand-over's approach (the holding hand
    would lean out in front with the object)."""
    from marionette.execution.visual_servo import (
        handover_approaches,
        looks_before_approach,
        servoed_tasks,
    )
    from marionette.planning.problem import load_problem
    from marionette.scenarios.plan_and_execute import _lean_for_view

    p = talos_plank
    specs = _visual(p)
    problem = load_problem(p.plan.doc["problem"]["source"])
    lean = _lean_for_view("talos", "plank", p.steps, specs, problem, p.robot_map, p.ctx)
    assert lean is not None
    handover_only = {
        s.index
        for s, spec in zip(p.steps, specs)
        if handover_approaches(s, spec)
        and servoed_tasks(p.steps, specs, True).get(s.index) == set(handover_approaches(s, spec))
    }
    assert handover_only, "the plank plan's hand-over approaches are servoed"
    expected = (set(servoed_tasks(p.steps, specs, True)) - handover_only) | looks_before_approach(
        p.steps, specs
    )
    assert set(lean.held) == expected and not handover_only & set(lean.held)
