"""The footstep process: message logic in-process, then the real `marionette footsteps run` over
loopback LCM."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from footsteps_checks import BALL
from tests_support import wait_for_line


def _object_poses(name: str, position, yaw: float = 0.0, utime: int = 0):
    from marionette import lcmt_object_pose, lcmt_object_poses

    pose = lcmt_object_pose()
    pose.utime = utime
    pose.object_name = name
    pose.position_world = list(map(float, position))
    pose.quaternion_world = [float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2))]
    pose.num_tags = 0
    pose.tag_id = []
    msg = lcmt_object_poses()
    msg.utime = utime
    msg.camera_name = "head"
    msg.num_objects = 1
    msg.objects = [pose]
    return msg


def _walk_status(step: int, left=(0.0, 0.085, 0.0, 0.0), right=(0.0, -0.085, 0.0, 0.0)):
    from marionette import lcmt_walk_status

    msg = lcmt_walk_status()
    msg.current_step_index = step
    msg.phase = "standing" if step < 0 else "left_swing"
    msg.left_foot = list(left)
    msg.right_foot = list(right)
    return msg


def test_grasp_node_plans_then_replans_only_unstarted_steps(build_dir, robot):
    from marionette.footsteps.node import FootstepNode, NodeOptions

    node = FootstepNode(NodeOptions(mode="grasp"), robot=robot)
    assert node.update(0) is None  # no stance, no target yet
    node.on_walk_status(_walk_status(-1))
    node.on_object_poses(_object_poses("ball", BALL))
    first = node.update(1)
    assert first.plan_id == 1 and first.first_step_index == 0
    assert first.num_steps == len(first.steps) >= 7
    assert [s.index for s in first.steps] == list(range(first.num_steps))
    assert node.update(2) is None  # nothing changed: no replan
    # The robot has started step 2 and the ball rolled 5 cm: steps 0..2 stay, the rest moves.
    node.on_walk_status(_walk_status(2))
    node.on_object_poses(_object_poses("ball", BALL + [0.05, 0.0, 0.0]))
    second = node.update(3)
    assert second.plan_id == 2 and second.first_step_index == 3
    assert second.steps[0].index == 3
    old = {s.index: (s.x, s.y, s.yaw) for s in first.steps}
    kept = node.last_plan.steps[:3]
    assert all(np.allclose(old[s.index], (s.pose[0], s.pose[1], s.pose[3])) for s in kept)
    assert not np.allclose(
        old[second.steps[-1].index][:2], (second.steps[-1].x, second.steps[-1].y)
    )
    assert node.last_solve_ms < 1000.0
    # A status back to "standing" (-1) does not make executed steps replannable again.
    node.on_walk_status(_walk_status(-1))
    node.on_object_poses(_object_poses("ball", BALL + [0.05, 0.03, 0.0]))
    third = node.update(4)
    assert third.first_step_index == 3 and third.steps[0].index == 3


def test_a_failed_first_plan_is_tried_again_when_the_object_moves(build_dir, robot):
    from marionette.footsteps.errors import PlanningFailed
    from marionette.footsteps.node import FootstepNode, NodeOptions

    node = FootstepNode(NodeOptions(mode="step-over"), robot=robot)
    node.on_walk_status(_walk_status(-1))
    node.on_object_poses(_object_poses("bar", [-0.5, 0.0, 0.0], yaw=np.pi / 2))  # behind
    with pytest.raises(PlanningFailed):
        node.update(1)
    node.on_object_poses(_object_poses("bar", [1.0, 0.0, 0.0], yaw=np.pi / 2))
    plan = node.update(2)
    assert plan is not None and plan.plan_id == 1 and plan.first_step_index == 0


@pytest.mark.parametrize("turn", [-0.17, 0.0, 0.12])
def test_a_bar_along_its_frame_y_is_read_with_its_axis_and_an_axis_has_no_sign(turn):
    """A tagged bar lies along its frame's y (``--bar-axis-yaw`` pi/2): its axis yaw is its
    frame's yaw + pi/2, and of the two directions of an axis the node keeps the one nearest
    its last estimate (a frame seen half a turn round, or a yaw wrapping past pi, does not flip
    the bar under the planner)."""
    from marionette.footsteps.node import FootstepNode, NodeOptions

    node = FootstepNode(NodeOptions(mode="step-over", bar_axis_yaw=np.pi / 2))
    node.on_object_poses(_object_poses("bar", [1.0, 0.0, 0.0], yaw=turn))
    assert node.object_pose[3] == pytest.approx(np.pi / 2 + turn, abs=1e-9)
    for frame_yaw in (turn + np.pi, turn - np.pi + 0.01, turn + 2 * np.pi - 0.01):
        node.on_object_poses(_object_poses("bar", [1.0, 0.0, 0.0], yaw=frame_yaw))
        expected = np.pi / 2 + turn + np.angle(np.exp(2j * (frame_yaw - turn))) / 2
        assert node.object_pose[3] == pytest.approx(expected, abs=1e-9), frame_yaw


@pytest.mark.parametrize("seed", range(5))
def test_the_target_point_is_carried_by_the_tracked_object(seed):
    """``--target-point``: the hand's target is a point fixed in the tracked object's frame (the
    ball resting on its tagged pedestal), p + R p_O whatever the object's rotation (Pinocchio's
    quaternion as the reference)."""
    import pinocchio as pin

    from marionette import lcmt_object_pose, lcmt_object_poses
    from marionette.footsteps.node import FootstepNode, NodeOptions

    rng = np.random.default_rng(seed)
    point = rng.uniform(-0.5, 1.0, 3)
    p = rng.uniform(-2.0, 2.0, 3)
    q = pin.Quaternion(pin.exp3(rng.uniform(-2.0, 2.0, 3)))
    o = lcmt_object_pose()
    o.object_name = "pedestal"
    o.position_world = p.tolist()
    # A quaternion need not arrive normalised: the node normalises it.
    o.quaternion_world = [2.0 * v for v in (q.w, q.x, q.y, q.z)]
    o.tag_id = []
    msg = lcmt_object_poses()
    msg.objects, msg.num_objects = [o], 1
    node = FootstepNode(NodeOptions(mode="grasp", target="pedestal", target_point=tuple(point)))
    node.on_object_poses(msg)
    assert node.object_pose[:3] == pytest.approx(p + q.matrix() @ point, abs=1e-12)


def test_malformed_object_poses_are_ignored(build_dir, robot):
    from marionette.footsteps.node import FootstepNode, NodeOptions

    node = FootstepNode(NodeOptions(mode="grasp"), robot=robot)
    node.on_object_poses(_object_poses("ball", [np.nan, 0.0, 0.5]))
    node.on_object_poses(_object_poses("not_the_ball", [1.0, 0.0, 0.5]))
    assert node.object_pose is None


def test_unknown_mode_is_rejected():
    from marionette.footsteps.errors import FootstepError
    from marionette.footsteps.node import FootstepNode, NodeOptions

    with pytest.raises(FootstepError, match="mode must be"):
        FootstepNode(NodeOptions(mode="dance"))
    with pytest.raises(FootstepError, match="axis yaw must be finite"):
        FootstepNode(NodeOptions(mode="step-over", bar_axis_yaw=float("nan")))


def test_footsteps_process_publishes_plans_over_lcm(build_dir, lcm_url, lcm_env):
    from marionette import channels, lcmt_footstep_plan
    from marionette.lcm_bus import LcmBus, MessageLog

    cmd = [
        sys.executable,
        "-m",
        "marionette.cli",
        "footsteps",
        "run",
        "--mode",
        "step-over",
        "--goal",
        "2.0",
        "0.0",
        "0.0",
        "--bar-radius",
        "0.02",
        "--duration",
        "30",
    ]
    proc = subprocess.Popen(
        cmd, env=lcm_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        assert wait_for_line(proc.stdout, "footsteps: ready", 30.0), "process did not start"
        with LcmBus(lcm_url) as bus:
            log = MessageLog(bus, channels.FOOTSTEP_PLAN, lcmt_footstep_plan)
            bus.start()
            deadline = time.monotonic() + 20.0
            while not log.messages and time.monotonic() < deadline:
                bus.publish(channels.WALK_STATUS, _walk_status(-1))
                bus.publish(
                    channels.OBJECT_POSES, _object_poses("bar", [1.0, 0.0, 0.02], yaw=np.pi / 2)
                )
                time.sleep(0.1)
            assert log.wait_for(lambda m: len(m) >= 1, 5.0), "no FOOTSTEP_PLAN received"
            plan = log.latest()
            assert plan.first_step_index == 0 and plan.num_steps >= 8
            assert sum(1 for s in plan.steps if s.num_via == 2) == 2  # two bar crossings
            # The bar moves: a new plan, the crossing footprints following it.
            for _ in range(20):
                bus.publish(
                    channels.OBJECT_POSES, _object_poses("bar", [1.05, 0.0, 0.02], yaw=np.pi / 2)
                )
                bus.publish(channels.WALK_STATUS, _walk_status(-1))
                if log.wait_for(lambda m: len(m) >= 2, 0.2):
                    break
            assert log.latest().plan_id == 2
            crossing = [s for s in log.latest().steps if s.num_via == 2]
            # Their passage points straddle the bar at its new place (x = 1.05).
            assert len(crossing) == 2
            assert all(s.via[0][0] < 1.05 < s.via[1][0] for s in crossing)
            assert all(abs(0.5 * (s.via[0][0] + s.via[1][0]) - 1.05) < 0.02 for s in crossing)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
