"""The scenes of models/scenes: what their YAML promises, and that TALOS can do the plank
experiment from where it stands (reach with both grippers, tags in the head camera's view)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yaml

from marionette import MODELS_DIR, robots
from marionette.models.mjcf import CAMERA_FOVY_DEG, CAMERA_HEIGHT, CAMERA_WIDTH
from marionette.models.semantics import Placement

SCENES = sorted(p.stem for p in (MODELS_DIR / "scenes").glob("*.yaml"))


def _scene(name):
    return yaml.safe_load((MODELS_DIR / "scenes" / f"{name}.yaml").read_text())


def _pose(d) -> pin.SE3:
    return Placement(tuple(d["xyz"]), tuple(d["xyzw"])).se3()


def test_the_scenes_of_the_demos_are_there():
    assert {"talos_plank", "talos_walk", "tiago_deburr", "ur10_box", "ur10_drill"} <= set(SCENES)


@pytest.mark.parametrize("name", SCENES)
def test_every_scene_declaration_loads(name):
    from marionette.models.scenes import load_scene

    scene = load_scene(MODELS_DIR / "scenes" / f"{name}.yaml")
    assert scene.name == name


@pytest.mark.parametrize("name", SCENES)
def test_scene_objects_exist_and_tags_are_unique(name):
    scene = _scene(name)
    robots.robot(scene["robot"])
    ids = [t.id for t in robots.semantics(scene["robot"]).tags]
    for o in scene["objects"]:
        obj = robots.load_object(o["object"])
        assert o["sim"] in ("free", "mocap")
        _pose(o["pose"])
        ids += [t.id for t in obj.semantics.tags]
    assert len(ids) == len(set(ids)), f"{name}: a tag id appears twice: {sorted(ids)}"
    assert (MODELS_DIR / "scenes" / f"{name}.xml").is_file()


def _talos_with_gripper_frames():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    frames = {}
    for g in robots.semantics("talos").grippers:
        parent = model.getFrameId(g.link)
        f = model.frames[parent]
        frames[g.name] = model.addFrame(
            pin.Frame(
                g.name, f.parentJoint, parent, f.placement * g.pose.se3(), pin.FrameType.OP_FRAME
            )
        )
    return model, frames


def _plank_handle(handle: str) -> pin.SE3:
    scene = _scene("talos_plank")
    X_WP = _pose(next(o for o in scene["objects"] if o["name"] == "plank")["pose"])
    return X_WP * robots.load_object("plank").semantics.handle(handle).pose.se3()


def _reach(model, q0, frame: int, X_target: pin.SE3, iters: int = 1500) -> tuple[float, np.ndarray]:
    """Damped least squares on [both soles where they are (6D each), the gripper on the
    target (6D), the centre of mass above the middle of the feet (x, y)], joints clamped to
    their limits; returns the final task error norm and configuration."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, q0)
    feet = [
        (model.getFrameId(f), data.oMf[model.getFrameId(f)].copy())
        for f in robots.robot("talos").sole_frames
    ]
    mid = 0.5 * (feet[0][1].translation + feet[1][1].translation)
    q = q0.copy()
    for _ in range(iters):
        pin.framesForwardKinematics(model, data, q)
        pin.computeJointJacobians(model, data, q)
        errors, jacobians = [], []
        for fid, X in [*feet, (frame, X_target)]:
            errors.append(pin.log6(data.oMf[fid].inverse() * X).vector)
            jacobians.append(pin.getFrameJacobian(model, data, fid, pin.LOCAL))
        com = pin.centerOfMass(model, data, q)
        errors.append(mid[:2] - com[:2])
        jacobians.append(pin.jacobianCenterOfMass(model, data, q)[:2])
        e, J = np.concatenate(errors), np.vstack(jacobians)
        dq = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(e.size), e)
        q = np.clip(
            pin.integrate(model, q, 0.5 * dq), model.lowerPositionLimit, model.upperPositionLimit
        )
    return float(np.linalg.norm(e)), q


@pytest.mark.parametrize(
    "gripper, handle",
    [
        ("talos/right_gripper", "plank/H1"),
        ("talos/left_gripper", "plank/H2"),
        ("talos/right_gripper", "plank/H3"),
        ("talos/left_gripper", "plank/H4"),
        ("talos/left_gripper", "plank/H6"),
        ("talos/left_gripper", "plank/H8"),
    ],
)
def test_talos_reaches_the_plank_handles_without_moving_its_feet(gripper, handle):
    """The grasps of the thesis' experiment (sec. 3.4.2): from half-sitting, with the feet in
    place and the centre of mass above them, the right gripper reaches the handles approached
    from its side (H1 top, H3 bottom) and the left gripper the others (H6, H8: H2, H4 turned
    about their approach, the left hand's two fingertips on the other face), pre-grasp and
    grasp, to 0.1 mm."""
    model, frames = _talos_with_gripper_frames()
    q0 = robots.reference_configuration("talos", model)
    g = robots.semantics("talos").gripper(gripper)
    h = robots.load_object("plank").semantics.handle(handle)
    X_WH = _plank_handle(handle)
    pregrasp = X_WH * pin.SE3(np.eye(3), -(g.clearance + h.clearance) * np.asarray(h.approach))
    error, q_grasp = _reach(model, q0, frames[gripper], X_WH)
    assert error < 1e-4
    error, _ = _reach(model, q_grasp, frames[gripper], pregrasp)  # backing off the grasp
    assert error < 1e-4


def test_talos_head_camera_sees_the_plank_and_table_tags_when_looking_down():
    """Half-sitting, torso pitched 0.2 rad and head 0.78 rad down (within limits): every tag of
    the plank's front face, of its end face on top and of the table projects inside the 640 x 480
    image, facing the camera (MuJoCo camera model: pinhole, fovy 45 deg, square pixels)."""
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    q = robots.reference_configuration("talos", model)
    for joint, value in (("torso_2_joint", 0.2), ("head_1_joint", 0.78)):
        jm = model.joints[model.getJointId(joint)]
        assert model.lowerPositionLimit[jm.idx_q] < value < model.upperPositionLimit[jm.idx_q]
        q[jm.idx_q] = value
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    X_WC = data.oMf[model.getFrameId(robots.robot("talos").camera_frame)]
    f = (CAMERA_HEIGHT / 2) / np.tan(np.radians(CAMERA_FOVY_DEG) / 2)
    scene = _scene("talos_plank")
    seen = []
    for o in scene["objects"]:
        X_WO = _pose(o["pose"])
        for t in robots.load_object(o["object"]).semantics.tags:
            X_CT = X_WC.inverse() * X_WO * t.pose.se3()
            if X_CT.rotation[:, 2] @ X_CT.translation >= 0:
                continue  # printed face turned away (the plank's back face)
            s = t.size / 2
            for corner in ([-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0]):
                p = X_CT.act(np.array(corner, dtype=float))
                u, v = f * p[0] / p[2] + CAMERA_WIDTH / 2, f * p[1] / p[2] + CAMERA_HEIGHT / 2
                assert p[2] > 0 and 0 < u < CAMERA_WIDTH and 0 < v < CAMERA_HEIGHT, (t.id, u, v)
            seen.append(t.id)
    assert sorted(seen) == [4, 5, 10, 11, 14, 15]  # 14, 15 on the end face on top


def test_talos_head_camera_keeps_the_pedestal_in_view_as_it_walks_up_to_it():
    """The grasp-walk's gaze (half-sitting, the head aimed at the pedestal's point by
    ``aim_head``): the pedestal's tag facing the robot projects whole inside the 640 x 480 image
    with the pedestal anywhere from 2 m down to 0.65 m ahead of the feet, 0.3 m to either side;
    nearer, the head's pitch limit lets it out (the last estimates come from before the stop)."""
    from marionette.scenarios.grasp_walk import GraspWalkSettings
    from marionette.scenarios.walking_scenario import aim_head

    model, _ = robots.load_pinocchio("talos", with_collision=False)
    data = model.createData()
    camera = model.getFrameId(robots.robot("talos").camera_frame)
    f = (CAMERA_HEIGHT / 2) / np.tan(np.radians(CAMERA_FOVY_DEG) / 2)
    (tag,) = [t for t in robots.load_object("pedestal").semantics.tags if t.id == 60]  # faces -x
    point = np.array(GraspWalkSettings().gaze_point)

    pin.framesForwardKinematics(model, data, robots.reference_configuration("talos", model))
    mid = sum(data.oMf[model.getFrameId(f"{s}_sole_link")].translation for s in ("left", "right"))
    mid = mid / 2

    def in_view(ahead: float, side: float) -> bool:
        X_WO = pin.SE3(np.eye(3), np.array([mid[0] + ahead, mid[1] + side, 0.0]))
        q = robots.reference_configuration("talos", model)
        for joint, value in aim_head("talos", X_WO.act(point)).items():
            q[model.joints[model.getJointId(joint)].idx_q] = value
        pin.framesForwardKinematics(model, data, q)
        X_CT = data.oMf[camera].inverse() * X_WO * tag.pose.se3()
        s = tag.size / 2
        for corner in ([-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0]):
            p = X_CT.act(np.array(corner, dtype=float))
            u, v = f * p[0] / p[2] + CAMERA_WIDTH / 2, f * p[1] / p[2] + CAMERA_HEIGHT / 2
            if not (p[2] > 0 and 0 < u < CAMERA_WIDTH and 0 < v < CAMERA_HEIGHT):
                return False
        return True

    assert all(in_view(d, y) for d in np.linspace(0.65, 2.0, 10) for y in (-0.3, 0.0, 0.3))
    assert not in_view(0.45, 0.0)


@pytest.mark.parametrize(
    "robot, scene, gripper",
    [("tiago", "tiago_deburr", "tiago/deburring_tool"), ("ur10", "ur10_drill", "ur10/drill")],
)
def test_every_hole_of_the_part_is_within_reach_of_the_tool(robot, scene, gripper):
    """From the scene's base placement (TIAGo's base kept still), the tool tip reaches every
    hole handle with its axis on the hole axis (mask 1 1 1 0 1 1): damped least squares from
    the reference posture, restarted from a few perturbed postures when it stalls."""
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    g = robots.semantics(robot).gripper(gripper)
    parent = model.getFrameId(g.link)
    fid = model.addFrame(
        pin.Frame(
            g.name,
            model.frames[parent].parentJoint,
            parent,
            model.frames[parent].placement * g.pose.se3(),
            pin.FrameType.OP_FRAME,
        )
    )
    data = model.createData()
    movable = np.ones(model.nv)
    if robots.robot(robot).base == "planar":
        movable[:3] = 0.0
    q_ref = robots.reference_configuration(robot, model)
    part = next(o for o in _scene(scene)["objects"] if o["object"] == "part")
    X_WP = _pose(part["pose"])
    rng = np.random.default_rng(0)
    starts = [q_ref] + [
        pin.integrate(model, q_ref, movable * rng.normal(scale=0.5, size=model.nv))
        for _ in range(6)
    ]
    for h in robots.load_object("part").semantics.handles:
        X = X_WP * h.pose.se3()
        mask = np.asarray(h.mask, dtype=float)
        best = np.inf
        for q in starts:
            for _ in range(800):
                pin.framesForwardKinematics(model, data, q)
                pin.computeJointJacobians(model, data, q)
                e = mask * pin.log6(data.oMf[fid].inverse() * X).vector
                J = mask[:, None] * pin.getFrameJacobian(model, data, fid, pin.LOCAL) * movable
                dq = J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), e)
                q = np.clip(
                    pin.integrate(model, q, 0.5 * dq),
                    model.lowerPositionLimit,
                    model.upperPositionLimit,
                )
            best = min(best, float(np.linalg.norm(e)))
            if best < 1e-6:
                break
        assert best < 1e-6, f"{h.name} out of reach ({best})"
