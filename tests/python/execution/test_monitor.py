"""Execution monitor (thesis 000 §3.4.4.1): residuals of the ur10-box plan's own grasp
and placement constraints. Along the planned path the grasp holds by construction (the planner
projected every sample on it), so the residual there must stay ~0; a box displaced in the gripper
by a known offset must give that offset back and fire after `consecutive` messages; a single
outlier must not fire. Then the same monitor in a live MuJoCo run: the weld of the held box is
broken and the box moved away, the supervisor fails with left_manifold and the robot holds."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pinocchio as pin
import pytest

from marionette import channels, lcmt_object_pose, lcmt_object_poses
from marionette.execution.monitor import ExecutionMonitor, MonitorNode, MonitorOptions, residual_of
from marionette.execution.supervisor import Supervisor, SupervisorOptions
from tests_support import controller_running


def _poses(objects: dict[str, pin.SE3], utime: int = 0) -> lcmt_object_poses:
    msg = lcmt_object_poses()
    msg.utime, msg.camera_name = utime, "motion_capture"
    for name, X in objects.items():
        p = lcmt_object_pose()
        p.utime, p.object_name = utime, name
        q = pin.Quaternion(X.rotation)
        p.position_world, p.quaternion_world = list(X.translation), [q.w, q.x, q.y, q.z]
        msg.objects.append(p)
    msg.num_objects = len(msg.objects)
    return msg


def _held_step(planned):
    return next(s for s in planned.steps if s.grasps and len(s.q) > 10)


def test_residual_is_the_relative_motion():
    X = pin.SE3(pin.rpy.rpyToMatrix(0.1, -0.2, 0.3), np.array([0.4, -0.1, 0.8]))
    offset = pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, 0.05), np.array([0.03, 0.0, -0.04]))
    position, angle = residual_of(X, X * offset)
    assert position == pytest.approx(0.05, abs=1e-12)  # 3-4-5
    assert angle == pytest.approx(0.05, abs=1e-12)


def test_planned_carry_stays_on_the_grasp_manifold(ur10_box):
    monitor = ExecutionMonitor(ur10_box.model, ur10_box.ctx)
    step = _held_step(ur10_box)
    monitor.begin_step(step)
    ((_gripper, handle),) = step.grasps.items()
    obj = ur10_box.ctx.handle_objects[handle]
    for k in range(0, len(step.q), max(1, len(step.q) // 50)):
        monitor.on_configuration(ur10_box.robot_map.robot_q(step.q[k]))
        assert (
            monitor.on_object_poses(_poses({obj: ur10_box.robot_map.object_pose(step.q[k], obj)}))
            is None
        )
    position, angle = monitor.max_residual[obj]
    assert position < 1e-4 and angle < 1e-4, (position, angle)


def test_box_slid_in_the_cup_fires_after_consecutive_messages(ur10_box):
    options = MonitorOptions(consecutive=3)
    monitor = ExecutionMonitor(ur10_box.model, ur10_box.ctx, options)
    step = _held_step(ur10_box)
    monitor.begin_step(step)
    ((gripper, handle),) = step.grasps.items()
    obj = ur10_box.ctx.handle_objects[handle]
    frame = ur10_box.model.getFrameId(ur10_box.ctx.gripper_frames[gripper])
    data = ur10_box.model.createData()
    slip = pin.SE3(np.eye(3), np.array([0.0, 0.03, 0.0]))  # 3 cm in the gripper frame
    fired = []
    for k in range(6):
        q_plan = step.q[min(k * 5, len(step.q) - 1)]
        q = ur10_box.robot_map.robot_q(q_plan)
        monitor.on_configuration(q)
        X_WO = ur10_box.robot_map.object_pose(q_plan, obj)
        if k == 1:  # one outlier, then back: not a failure
            X_WO = X_WO * pin.SE3(np.eye(3), np.array([0.05, 0.0, 0.0]))
        if k >= 3:  # slid: X_WO = X_WG slip X_GO
            pin.framesForwardKinematics(ur10_box.model, data, q)
            X_WG = data.oMf[frame]
            X_WO = X_WG * slip * X_WG.actInv(X_WO)
        fired.append(monitor.on_object_poses(_poses({obj: X_WO})))
    assert fired[:5] == [None] * 5, fired
    residual = fired[5]
    assert residual is not None and residual.object_name == obj
    assert residual.constraint == f"grasp by {gripper}"
    # Up to the plan's own grasp residual along the path (< 0.1 mm, previous test).
    assert residual.position == pytest.approx(0.03, abs=1e-4) and residual.angle < 1e-4
    assert "30.0 mm" in residual.describe()


def test_placed_object_moved_fires_on_placement(ur10_box):
    monitor = ExecutionMonitor(ur10_box.model, ur10_box.ctx, MonitorOptions(consecutive=2))
    # A transit in the free state with the box placed: the plan's last step (the retreat after the
    # release) without its transition's grasps, as a `Loop | f` step has none (this plan has no
    # such step).
    last = ur10_box.steps[-1]
    step = dataclasses.replace(
        last, grasps={}, grasps_from={}, grasps_to={}, parent_grasps_from={}, parent_grasps_to={}
    )
    monitor.begin_step(step)
    monitor.on_configuration(ur10_box.robot_map.robot_q(step.q[0]))
    X = ur10_box.robot_map.object_pose(step.q[0], "box")
    assert monitor.on_object_poses(_poses({"box": X})) is None
    pushed = pin.SE3(X.rotation, X.translation + np.array([0.0, 0.0, 0.01]))  # 1 cm: tolerated
    assert monitor.on_object_poses(_poses({"box": pushed})) is None
    fallen = pin.SE3(X.rotation @ pin.rpy.rpyToMatrix(0.3, 0.0, 0.0), X.translation)
    assert monitor.on_object_poses(_poses({"box": fallen})) is None
    residual = monitor.on_object_poses(_poses({"box": fallen}))
    assert residual is not None and residual.constraint == "placement"
    assert residual.angle == pytest.approx(0.3, abs=1e-9)


MUJOCO = (
    "--robot",
    "ur10",
    "--backend",
    "mujoco",
    "--speed",
    "3",
    "--camera-rate",
    "0",
    "--status-rate",
    "100",
)


@pytest.fixture
def ur10_box_mujoco(build_dir, lcm_url, tmp_path):
    from marionette.scenarios import SCENARIOS

    with controller_running(
        build_dir, lcm_url, tmp_path / "logs", *MUJOCO, "--scene", str(SCENARIOS["ur10-box"].scene)
    ) as client:
        yield client


@pytest.mark.slow
def test_box_pulled_out_of_the_gripper_fails_the_step_and_holds(ur10_box_mujoco, ur10_box):
    """Live: the ur10-box plan in MuJoCo with the ground truth relayed as OBJECT_POSES (motion
    capture); once the box is carried, its weld is broken and the box put back on the table: the
    monitor reports the residual, the FSM fails with left_manifold and the controller holds."""
    c = ur10_box_mujoco
    q0 = np.array(ur10_box.plan.doc["problem"]["q_init"])
    for name in ur10_box.robot_map.objects:
        c.move_object(name, ur10_box.robot_map.object_pose(q0, name))
    c.wait_time(0.3)

    def relay(msg):  # perception stand-in: the simulator's poses as a motion-capture system
        msg.camera_name = "motion_capture"
        c.bus.publish(channels.OBJECT_POSES, msg)

    c.bus.subscribe(channels.SIM_OBJECT_POSES, lcmt_object_poses, relay)
    node = MonitorNode(c.bus, ExecutionMonitor(ur10_box.model, ur10_box.ctx), ur10_box.steps)
    sup = Supervisor(
        c,
        ur10_box.steps,
        ur10_box.specs,
        ur10_box.robot_map,
        SupervisorOptions(max_joint_velocity=1.0),
        "ur10_box",
    )
    out = {}
    runner = threading.Thread(target=lambda: out.setdefault("result", sup.run()))
    runner.start()
    held = _held_step(ur10_box)
    c.wait(
        lambda c: sup.step_index == held.index and sup.status == "running", 120.0, "the carry step"
    )
    c.wait_time(0.3)
    assert not node.events, f"false alarm before the perturbation: {node.events}"
    before = dict(node.monitor.max_residual)
    ((gripper, handle),) = held.grasps.items()
    obj = ur10_box.ctx.handle_objects[handle]
    c.detach(f"grasp/{gripper}/{obj}")
    c.move_object(obj, ur10_box.robot_map.object_pose(q0, obj))
    runner.join(timeout=120.0)
    result = out["result"]
    assert result.state == "failed" and result.reason.startswith("left_manifold"), result.reason
    assert obj in result.reason and "mm" in result.reason  # the residual is reported
    assert node.events and node.events[0][1].position > 0.02
    print(
        f"residuals before the perturbation (max per object, m, rad): {before}; reported: "
        f"{result.reason}"
    )
    c.wait(lambda c: c.status.mode == "holding", 10.0, "the hold")
