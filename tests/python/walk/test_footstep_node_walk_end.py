"""The footstep process against a walk that reaches its end (found running it against the
controller, grasp-walk demo): once only the last, posture-bound step is left and the target has
not moved, step progress must not produce a plan; a move at that point still does."""

from __future__ import annotations

import numpy as np
import pytest

BALL = np.array([1.3, -0.1, 0.880])  # the grasp-walk demo's ball (6 steps ahead)


@pytest.fixture(scope="module")
def robot():
    from marionette.footsteps.robot_model import walking_robot

    return walking_robot("talos")


def _status(step: int):
    from marionette import lcmt_walk_status

    msg = lcmt_walk_status()
    msg.current_step_index = step
    msg.phase = "standing" if step < 0 else "right_swing"
    msg.left_foot, msg.right_foot = [0.0, 0.085, 0.0, 0.0], [0.0, -0.085, 0.0, 0.0]
    return msg


def _ball(position):
    from marionette import lcmt_object_pose, lcmt_object_poses

    o = lcmt_object_pose()
    o.object_name = "ball"
    o.position_world, o.quaternion_world = list(map(float, position)), [1.0, 0.0, 0.0, 0.0]
    o.tag_id = []
    msg = lcmt_object_poses()
    msg.objects, msg.num_objects = [o], 1
    return msg


@pytest.mark.slow
def test_the_walk_ends_when_only_the_posture_step_is_left(build_dir, robot):
    from marionette.footsteps.node import FootstepNode, NodeOptions

    node = FootstepNode(NodeOptions(mode="grasp"), robot=robot)
    node.on_walk_status(_status(-1))
    node.on_object_poses(_ball(BALL))
    first = node.update(1)
    n = first.num_steps
    # Every step start up to the penultimate one is a (warm-started) recomputation that keeps
    # the step count: the target did not move.
    for step in range(n - 2):
        node.on_walk_status(_status(step))
        plan = node.update(2 + step)
        if plan is not None:
            assert plan.first_step_index == step + 1
            assert plan.steps[-1].index == n - 1, "no step appended for an unmoved target"
    node.on_walk_status(_status(n - 2))  # the penultimate step starts
    assert node.update(100) is None
    node.on_walk_status(_status(n - 1))
    assert node.update(101) is None
    # The ball moves while the penultimate step is in progress: new steps are appended (the
    # planner's answer when only the posture-bound step is left).
    node2 = FootstepNode(NodeOptions(mode="grasp"), robot=robot)
    node2.on_walk_status(_status(-1))
    node2.on_object_poses(_ball(BALL))
    n2 = node2.update(1).num_steps
    node2.on_walk_status(_status(n2 - 2))
    node2.on_object_poses(_ball(np.asarray(BALL) + [0.0, -0.1, 0.0]))
    moved = node2.update(2)
    assert moved is not None and moved.first_step_index == n2 - 1
    assert moved.steps[-1].index > n2 - 1, "a moved target still gets new steps"
