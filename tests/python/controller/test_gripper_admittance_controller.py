"""The gripper_admittance task kind in marionette-controller (thesis 000 §3.2.4.3): TALOS in
MuJoCo closes its right gripper with nothing between the fingers — it reaches its closed position
in position control and never reports a contact (the TALOS MJCF moves the driven link only, so
its fingertips never touch anything: the contact case is tests/cpp/sot/gripper_admittance_test.cc
on tests/data/gripper_bench.xml); the entity's signals are listed and read by `marionette dg`;
a bad parameter is refused with its name."""

from __future__ import annotations

import numpy as np
import pytest

from marionette import robots
from marionette.control.introspection import GraphClient
from marionette.control.spec import ControllerSpec, TaskSpec

TALOS = robots.robot("talos")
CLOSED, OPEN = -1.0, -0.02


def _stack(controller_id: int, admittance: TaskSpec) -> ControllerSpec:
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    others = [
        model.names[j]
        for j in range(1, model.njoints)
        if model.joints[j].nv == 1 and model.names[j] != "gripper_right_joint"
    ]
    return ControllerSpec(
        controller_id,
        f"grip{controller_id}",
        [
            TaskSpec("left_foot", "se3", 0, frame="left_sole_link", gain=10.0),
            TaskSpec("right_foot", "se3", 0, frame="right_sole_link", gain=10.0),
            TaskSpec("com", "com", 0, gain=10.0),
            admittance,
            TaskSpec("posture", "posture", 2, gain=1.0, joints=others),
        ],
        max_switch_velocity_jump=0.05,
    )


def _admittance(**parameters: float) -> TaskSpec:
    p = {"force_target": 5.0, "force_threshold": 4.0, "closing_direction": -1.0, **parameters}
    return TaskSpec(
        "right_grip",
        "gripper_admittance",
        1,
        gain=2.0,
        reference=[CLOSED],
        joints=["gripper_right_joint"],
        parameters=p,
    )


@pytest.mark.slow
def test_talos_gripper_closes_to_its_limit_without_contact(run_controller, lcm_url):
    with (
        run_controller(
            "--robot", "talos", "--scene", str(TALOS.mjcf), "--speed", "0", "--camera-rate", "0"
        ) as c,
        GraphClient(lcm_url) as dg,
    ):
        c.send_spec(_stack(1, _admittance()))
        c.wait(
            lambda c: c.status.mode == "running" and c.status.active_controller_id == 1,
            30.0,
            "the controller",
        )
        listing = dg.ls()
        assert "c1_right_grip_feature (FeatureGripperAdmittance)" in listing, listing
        for signal in (
            "force",
            "force_filtered",
            "phase",
            "measured_position",
            "input effort : vector",
            "<- device.effort",
        ):
            assert signal in listing, signal
        # 0.98 rad at the 0.1 rad/s ramp: ~10 s of controller time, then settled.
        c.wait_time(12.0)
        values = dg.get(
            "c1_right_grip_feature.phase",
            "c1_right_grip_feature.force_filtered",
            "c1_right_grip_feature.measured_position",
        )
        assert float(values["c1_right_grip_feature.phase"]) == 0.0, (
            "no contact: still in position control"
        )
        assert abs(float(values["c1_right_grip_feature.force_filtered"])) < 4.0
        measured = c.joint_positions()["gripper_right_joint"]
        assert abs(measured - CLOSED) < 5e-3, measured
        assert abs(float(values["c1_right_grip_feature.measured_position"]) - measured) < 5e-3
        assert c.task_error("right_grip") < 0.01
        left = c.joint_positions()["gripper_left_joint"]
        assert abs(left - OPEN) < 5e-3, "the posture kept the other gripper open"


def test_bad_admittance_parameter_is_refused_by_name(run_controller):
    with run_controller("--robot", "talos", "--backend", "kinematic", "--camera-rate", "0") as c:
        bad = _admittance(force_threshold=6.0)  # above the 5 N target: no switch would happen
        c.send_spec(_stack(1, bad))
        c.wait(lambda c: "force_threshold" in c.status.last_rejection, 20.0, "the refusal")
        assert "task 'right_grip'" in c.status.last_rejection
        assert "must be below force_target" in c.status.last_rejection
        assert np.isfinite(c.utime())
