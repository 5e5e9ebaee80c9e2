"""TIAGo's planar base is a degree of freedom of the controller's model that nothing executes (the
MuJoCo device commands the 1-DoF joints; the scene holds the base): every controller holds its
three velocities at zero at level 0 (sot::FeatureHeldVelocities). Without that, the least-norm
solution reached a tool target with the base, the command's base drifted away and the arm did
not move (the deburr servo stalled on it with 0.64 m of commanded base drift)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.control.client import configuration_from_state, pose_to_vector
from marionette.control.introspection import GraphClient
from marionette.control.spec import ControllerSpec, TaskSpec

FRAME = "arm_7_link"


def test_tiago_reaches_a_sideways_target_with_its_arm_not_its_base(run_controller, lcm_url):
    model, _ = robots.load_pinocchio("tiago", with_collision=False)
    data = model.createData()
    fid = model.getFrameId(FRAME)

    def frame(q):
        pin.framesForwardKinematics(model, data, q)
        return pin.SE3(data.oMf[fid])

    with (
        run_controller("--robot", "tiago", "--speed", "0", "--camera-rate", "0") as c,
        GraphClient(lcm_url) as dg,
    ):
        q0 = configuration_from_state(model, c.state)
        # 6 cm sideways and 4 cm up: the base would do the sideways part for free
        target = pin.SE3(frame(q0).rotation, frame(q0).translation + np.array([0.0, 0.06, 0.04]))
        c.send_spec(
            ControllerSpec(
                1,
                "reach",
                [
                    TaskSpec(
                        "reach",
                        "se3",
                        0,
                        frame=FRAME,
                        mask=(1, 1, 1, 0, 0, 0),
                        gain=5.0,
                        reference=pose_to_vector(target).tolist(),
                    ),
                    TaskSpec("posture", "posture", 1, gain=1.0),
                ],
                max_switch_velocity_jump=10.0,
            )
        )
        c.wait(
            lambda c: c.status.mode == "running" and c.status.active_controller_id == 1,
            30.0,
            "the controller",
        )
        c.wait_time(4.0)
        command = dg.get("command.configuration")["command.configuration"]
        q = configuration_from_state(model, c.state)
        np.testing.assert_allclose(
            command[:4], q0[:4], atol=1e-4, err_msg="the commanded base moved"
        )
        np.testing.assert_allclose(q[:4], q0[:4], atol=1e-3, err_msg="the simulated base moved")
        reached = np.linalg.norm(frame(q).translation - target.translation)
        # the MuJoCo joint servos sag a few mm under gravity; the base would have left 6 cm
        assert reached < 0.01, f"the arm stopped {reached * 1e3:.1f} mm from the target"
        assert c.status.task_error_norm[0] < 1e-3, (
            f"the task error stayed at {c.status.task_error_norm[0]:.4f}"
        )
