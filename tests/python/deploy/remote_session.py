"""What a user's laptop does against a controller on another machine (run by test_two_hosts in
host B): wait for the controller, start a UR10 stack, stream a 10 cm tool motion, read and set a
gain through introspection, and print what it measured as JSON."""

from __future__ import annotations

import json
import sys

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.control.client import ControllerClient, configuration_from_state, pose_to_vector
from marionette.control.introspection import GraphClient
from marionette.control.spec import ControllerSpec, TaskSpec, reference_chunk


def main(url: str) -> dict:
    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    data = model.createData()
    tool = model.getFrameId("tool0")
    with ControllerClient(url) as c, GraphClient(url) as dg:
        c.wait_ready(60.0)
        c.send_spec(
            ControllerSpec(
                1,
                "arm",
                [
                    TaskSpec("tool", "se3", 0, frame="tool0", gain=5.0, streamed=True),
                    TaskSpec("posture", "posture", 1, gain=1.0),
                ],
            )
        )
        c.wait(lambda c: c.status.active_controller_id == 1, 30.0, "the arm controller")
        q = configuration_from_state(model, c.state)
        pin.framesForwardKinematics(model, data, q)
        start = pin.SE3(data.oMf[tool])
        s = np.linspace(0.0, 1.0, 1000)
        blend = 10 * s**3 - 15 * s**4 + 6 * s**5
        target = start.translation + np.array([0.0, 0.0, -0.10])
        values = [
            pose_to_vector(
                pin.SE3(start.rotation, start.translation + b * (target - start.translation))
            )
            for b in blend
        ]
        c.send_reference(reference_chunk(1, "tool", c.utime() + 50_000, values, last=True))
        c.wait_time(2.5)
        q = configuration_from_state(model, c.state)
        pin.framesForwardKinematics(model, data, q)
        reached = data.oMf[tool].translation.copy()
        gain_before = float(dg.get("c1_posture.gain")["c1_posture.gain"])
        dg.set("c1_posture.gain", 2.0)
        gain_after = float(dg.get("c1_posture.gain")["c1_posture.gain"])
        return {
            "moved": float(np.linalg.norm(reached - start.translation)),
            "error": float(np.linalg.norm(reached - target)),
            "mode": c.status.mode,
            "rejected": int(c.status.num_rejected),
            "gain_before": gain_before,
            "gain_after": gain_after,
            "listing_has_solver": "c1_solver (Solver)" in dg.ls(),
        }


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1])))
