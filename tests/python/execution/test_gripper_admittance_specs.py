"""The factory's gripper admittance (thesis 000 §3.2.5.1: the transition that closes a
gripper adds the admittance task, kept while the grasp holds; release in reverse) on the TALOS
plank-flip plan, checked against the plan's own grasp bookkeeping, and the spec's wire format."""

from __future__ import annotations

import numpy as np
import pytest

from marionette import robots
from marionette.control.spec import SpecError, TaskSpec
from marionette.execution.factory import ADMITTANCE, build_specs, context_from_plan


@pytest.fixture(scope="module")
def talos_admittance(talos_plank):
    ctx = context_from_plan(
        talos_plank.plan.doc, talos_plank.robot, talos_plank.model, gripper_admittance=True
    )
    return ctx, build_specs(talos_plank.steps, ctx)


def test_admittance_tasks_follow_the_grasps(talos_plank, talos_admittance):
    _ctx, specs = talos_admittance
    joints = {g.name: g for g in robots.semantics("talos").grippers}
    seen_hold = seen_release = 0
    for step, spec in zip(talos_plank.steps, specs):
        tasks = {t.joints[0]: t for t in spec.tasks if t.kind == "gripper_admittance"}
        expected_hold = {joints[g].joint for g in step.grasps}
        expected_release = {joints[g].joint for g in step.released}
        assert set(tasks) == expected_hold | expected_release, step.transition
        for joint, t in tasks.items():
            g = next(g for g in joints.values() if g.joint == joint)
            releasing = joint in expected_release
            assert t.reference == [g.open_position if releasing else g.closed_position]
            assert t.parameters["release"] == float(releasing)
            assert t.parameters["closing_direction"] == -1.0  # closed -1.0 < open -0.02
            assert t.parameters["force_target"] == ADMITTANCE["force_target"] == 5.0
            assert t.parameters["force_threshold"] < t.parameters["force_target"]
            seen_hold += not releasing
            seen_release += releasing
        # the posture leaves the admittance joints alone, and only them
        (posture,) = [t for t in spec.tasks if t.kind == "posture"]
        if tasks:
            assert not set(posture.joints) & set(tasks)
            one_dof = [
                talos_plank.model.names[j]
                for j in range(1, talos_plank.model.njoints)
                if talos_plank.model.joints[j].nv == 1
            ]
            assert set(posture.joints) | set(tasks) == set(one_dof)
        else:
            assert not posture.joints
    assert seen_hold > 0 and seen_release > 0


def test_a_hand_over_keeps_the_releasing_grip_until_the_receiving_one_has_closed(
    talos_plank, talos_admittance
):
    """The plank flip's hand-over: the step that opens the first hand is the one whose lead-in
    closes the second (its grasp created by the step before). The releasing task holds its grip
    for the receiving gripper's whole closing ramp (``release_after``) and the arm waits for both
    ramps one after the other; a release with no gripper closing on the object waits nothing."""
    from marionette.execution.references import grip_change_s, grip_ramp_s

    ctx, specs = talos_admittance
    steps = talos_plank.steps
    by_joint = {g.joint: name for name, g in ctx.gripper_joints.items()}
    handovers = 0
    for k, (step, spec) in enumerate(zip(steps, specs)):
        previous = steps[k - 1] if k else None
        for t in spec.tasks:
            if t.kind != "gripper_admittance" or not t.parameters["release"]:
                continue
            gripper = by_joint[t.joints[0]]
            obj = ctx.handle_objects[step.released[gripper]]
            receivers = [
                g
                for g, h in (previous.created if previous else {}).items()
                if ctx.handle_objects[h] == obj and g != gripper
            ]
            if not receivers:
                assert "release_after" not in t.parameters, step.transition
                continue
            handovers += 1
            closing = max(
                grip_ramp_s(
                    abs(
                        ctx.gripper_joints[g].closed_position - ctx.gripper_joints[g].open_position
                    ),
                    {**ADMITTANCE, **ctx.gripper_joints[g].parameters},
                )
                for g in receivers
            )
            assert t.parameters["release_after"] == pytest.approx(closing)
            own = ctx.gripper_joints[gripper]
            opening = grip_ramp_s(abs(own.closed_position - own.open_position), t.parameters)
            assert grip_change_s(step, previous, spec, ctx.robot) == pytest.approx(
                closing + opening
            )
    assert handovers >= 1


def test_default_factory_has_no_admittance(talos_plank):
    assert not any(t.kind == "gripper_admittance" for s in talos_plank.specs for t in s.tasks)


def test_admittance_spec_round_trips_through_lcm(talos_admittance):
    _, specs = talos_admittance
    t = next(t for s in specs for t in s.tasks if t.kind == "gripper_admittance")
    back = TaskSpec.from_lcm(t.to_lcm())
    assert back.to_dict() == t.to_dict() and back.parameters == t.parameters
    assert TaskSpec.from_dict(t.to_dict()).to_dict() == t.to_dict()


def test_bad_admittance_specs_are_refused_with_the_reason():
    ok = dict(
        name="g",
        kind="gripper_admittance",
        priority=0,
        reference=[-1.0],
        joints=["gripper_left_joint"],
    )
    TaskSpec(**ok).check()
    with pytest.raises(SpecError, match="unknown parameters \\['force'\\]"):
        TaskSpec(**ok, parameters={"force": 5.0}).check()
    with pytest.raises(SpecError, match="one joint"):
        TaskSpec(**dict(ok, reference=[])).check()
    with pytest.raises(SpecError, match="only gripper_admittance tasks take parameters"):
        TaskSpec("p", "posture", 0, parameters={"force_target": 5.0}).check()


def _revolute_grippers():
    from marionette import robots

    out = []
    for name in robots.robot_names():
        for g in robots.semantics(name).grippers:
            if g.joint is not None and "lever_arm" not in g.admittance:
                out.append((name, g.name))
    return out


@pytest.mark.parametrize("robot,gripper", _revolute_grippers())
def test_a_hinge_jaws_lever_arm_is_the_radius_its_handle_point_turns_on(robot, gripper):
    """Eq. 3.13's d_axis-gripper from the kinematics (factory.hinge_lever_arm), against the
    chord of the circle the gripper frame's origin, carried by the jaw, describes when the jaw
    turns by delta: d = chord / (2 sin(delta / 2))."""
    import pinocchio as pin

    from marionette import robots
    from marionette.execution.factory import hinge_lever_arm

    model, _ = robots.load_pinocchio(robot, with_collision=False)
    g = robots.semantics(robot).gripper(gripper)
    d = hinge_lever_arm(model, g)
    jid = model.getJointId(g.joint) if model.existJointName(g.joint) else model.njoints
    if (
        jid >= model.njoints
        or model.joints[jid].nq != 1
        or "R" not in model.joints[jid].shortname()
    ):
        assert d is None  # a slide (or a joint the controller's model does not have)
        return
    data = model.createData()
    q = pin.neutral(model)
    pin.framesForwardKinematics(model, data, q)
    p_W = data.oMf[model.getFrameId(g.link)].act(np.array(g.pose.xyz))
    p_jaw = data.oMi[jid].actInv(p_W)  # the same point, carried by the jaw
    delta = 0.3
    q[model.joints[jid].idx_q] += delta
    pin.forwardKinematics(model, data, q)
    chord = np.linalg.norm(data.oMi[jid].act(p_jaw) - p_W)
    assert d == pytest.approx(chord / (2 * np.sin(delta / 2)), rel=1e-9)


def _jawed_grippers():
    return [
        (name, g.name)
        for name in robots.robot_names()
        for g in robots.semantics(name).grippers
        if g.joint is not None and g.name in robots.robot(name).jaws
    ]


@pytest.mark.parametrize("robot,gripper", _jawed_grippers())
def test_the_squeeze_lever_arm_is_the_jaws_closing_speed_by_pinocchio(robot, gripper):
    """Eq. 3.13 by virtual work over the jaws' linkage (factory.squeeze_lever_arm), against
    Pinocchio's Jacobians on the robot's URDF with its mimic joints made movable: each jaw's
    pressing point closes along the gripper's y at J (dq/ds), the mimics moving at their
    multiplier; the speeds' magnitudes summed. Two fingers on one slide give exactly 2."""
    import xml.etree.ElementTree as ET

    import pinocchio as pin

    from marionette.execution.factory import squeeze_lever_arm
    from marionette.models.jaw import Linkage
    from marionette.models.urdf import read_urdf

    desc = robots.robot(robot)
    g = robots.semantics(robot).gripper(gripper)
    root = ET.parse(desc.urdf).getroot()
    driver = next(j for j in root.iter("joint") if j.get("name") == g.joint)
    followers = {}
    for j in root.iter("joint"):
        m = j.find("mimic")
        if m is not None and m.get("joint") == g.joint:
            j.set("type", driver.get("type"))
            if j.find("axis") is None:
                ET.SubElement(j, "axis", xyz="1 0 0")
            if j.find("limit") is None:
                ET.SubElement(j, "limit", lower="-10", upper="10", effort="1", velocity="1")
            followers[j.get("name")] = (float(m.get("multiplier", 1)), float(m.get("offset", 0)))
    model = pin.buildModelFromXML(ET.tostring(root, encoding="unicode"))
    middle = (g.open_position + g.closed_position) / 2
    q = pin.neutral(model)
    ds = np.zeros(model.nv)  # joint velocities per unit of finger motion
    for name, (a, b) in {g.joint: (1.0, 0.0), **followers}.items():
        joint = model.joints[model.getJointId(name)]
        q[joint.idx_q] = a * middle + (0.0 if name == g.joint else b)
        ds[joint.idx_v] = a
    urdf = read_urdf(desc.urdf)
    linkage = Linkage(urdf, urdf.joints[g.joint], desc.jaws[gripper], g.link, g.pose.matrix())
    points = linkage.pressing_points(middle)
    assert points is not None and len(points) == 2
    for link, p in points:
        body = model.frames[model.getFrameId(link)]
        model.addFrame(
            pin.Frame(
                f"press_{link}",
                body.parentJoint,
                body.placement * pin.SE3(np.eye(3), p),
                pin.FrameType.OP_FRAME,
            )
        )
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    y = data.oMf[model.getFrameId(g.link)].rotation @ g.pose.matrix()[:3, 1]
    expected = 0.0
    for link, _ in points:
        J = pin.getFrameJacobian(
            model, data, model.getFrameId(f"press_{link}"), pin.LOCAL_WORLD_ALIGNED
        )
        expected += abs(y @ (J[:3] @ ds))
    lever = squeeze_lever_arm(robot, gripper)
    assert lever == pytest.approx(expected, rel=1e-4)
    if driver.get("type") == "prismatic" and followers:
        assert lever == pytest.approx(2.0, rel=1e-6)
