"""Initial-state estimation (thesis 000 §3.2.2): perturbed measurements project onto the right
graph state, and the plan resumes at the right step (steps already done are skipped)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette import channels, lcmt_object_pose, lcmt_object_poses
from marionette.execution.estimation import (
    estimate_state,
    first_step_to_run,
    measured_configuration,
    sensed_object_poses,
)
from marionette.lcm_bus import LcmBus
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.problem import load_problem


@pytest.fixture(scope="module")
def ur10_graph(ur10_box):
    return graph_from_settings(load_problem(ur10_box.plan.doc["problem"]["source"]))


def _perturbed(p, q_plan, rng):
    """Encoders off by ~2 mrad, the box seen 2 mm / 0.5° away."""
    q_robot = p.robot_map.robot_q(q_plan) + rng.normal(0.0, 0.002, p.model.nq)
    X = p.robot_map.object_pose(q_plan, "box")
    X = X * pin.exp6(np.r_[rng.normal(0, 0.002, 3), rng.normal(0, np.radians(0.5), 3)])
    return measured_configuration(q_plan, p.robot_map, q_robot, {"box": X})


def test_perturbed_start_of_each_step_is_recognised_and_resumed(ur10_box, ur10_graph):
    p = ur10_box
    rng = np.random.default_rng(3)
    for step in p.steps:
        estimate = estimate_state(ur10_graph, _perturbed(p, step.q[0], rng))
        expected = {step.start_state}
        if step.kind == "release" or step.transition.endswith("_23"):
            expected |= {"free", "ur10/gripper grasps box/top"}  # box grasped on the table: both
        assert estimate.state in expected, step.transition
        assert estimate.residual < 0.05
        assert first_step_to_run(p.steps, p.robot_map, estimate) == step.index, step.transition


def test_box_already_at_the_goal_means_nothing_left_to_do(ur10_box, ur10_graph):
    p = ur10_box
    estimate = estimate_state(
        ur10_graph, _perturbed(p, p.steps[-1].q[-1], np.random.default_rng(1))
    )
    assert estimate.state == "free"
    assert first_step_to_run(p.steps, p.robot_map, estimate) == len(p.steps)


def test_box_in_the_gripper_is_the_grasp_state(ur10_box, ur10_graph):
    p = ur10_box
    carry = next(s for s in p.steps if s.transition.endswith("_34"))
    q = carry.q[len(carry.q) // 2]  # mid-transfer, box in the air
    estimate = estimate_state(ur10_graph, _perturbed(p, q, np.random.default_rng(2)))
    assert estimate.state == "ur10/gripper grasps box/top"
    ranking = dict(estimate.ranking)
    assert ranking["free"] is None or ranking["free"] > 2 * estimate.residual  # box 5 cm up


class _Controller:
    """What sensed_object_poses needs of a controller client, on a real LCM bus: a clock that
    advances 0.1 s per wait round, each round handling what arrived. ``on_round`` runs first."""

    def __init__(self, bus: LcmBus, on_round) -> None:
        self.bus, self.t, self.on_round = bus, 0, on_round

    def utime(self) -> int:
        return self.t

    def wait(self, condition, timeout_s: float, what: str = "") -> None:
        while not condition(self):
            self.on_round(self.t)
            self.bus.handle(0.05)
            self.t += 100_000
            assert self.t < 60_000_000, f"never: {what}"


def _object_poses(obj: str, X: pin.SE3):
    msg, pose = lcmt_object_poses(), lcmt_object_pose()
    pose.object_name = obj
    q = pin.Quaternion(X.rotation)
    pose.position_world, pose.quaternion_world = list(X.translation), [q.w, q.x, q.y, q.z]
    msg.objects, msg.num_objects = [pose], 1
    return msg


def test_the_objects_at_start_are_what_the_camera_saw_and_the_others_are_said(lcm_url):
    X_box = pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, 0.3), np.array([0.6, -0.1, 0.8]))
    lines: list[str] = []
    with LcmBus(lcm_url) as bus:

        def sent(
            t: int,
        ) -> None:  # the camera sees the box from the third round on, never the plank
            if t >= 200_000:
                bus.publish(channels.OBJECT_POSES, _object_poses("box", X_box))

        client = _Controller(bus, sent)
        seen = sensed_object_poses(client, ["plank", "box"], 1.0, lines.append)
    assert set(seen) == {"box"}
    assert seen["box"].isApprox(X_box, 1e-9)
    assert client.t >= 1_000_000, "it looked for the whole second for the plank"
    assert lines == [
        "estimation: plank not seen by the camera within 1 s: at the plan's initial pose"
    ]


def test_without_an_object_sensor_the_objects_are_where_the_plan_starts_them(lcm_url):
    lines: list[str] = []
    with LcmBus(lcm_url) as bus:
        client = _Controller(bus, lambda t: None)
        assert sensed_object_poses(client, ["box"], 0.0, lines.append) == {}
    assert client.t == 0, "nothing waited for"
    assert lines == ["estimation: no object sensor: box at the plan's initial pose"]
