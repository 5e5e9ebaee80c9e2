"""marionette-controller walks TALOS in MuJoCo from a footstep plan sent over LCM: a
controller spec whose feet and CoM tasks take their references from the pattern generator
("walk:" reference channels), FOOTSTEP_PLAN in, WALK_STATUS out; the robot walks the steps,
stops, and the ZMP it reports from the soles' contact wrenches stays under its feet. The run is
recorded and replayed offline from the controller's journal (plans journaled like every input)."""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from marionette import (
    channels,
    lcmt_footstep,
    lcmt_footstep_plan,
    lcmt_robot_state,
    lcmt_walk_status,
    robots,
)
from marionette.control.replay_cli import replay_controller
from marionette.execution.walking import walking_spec
from marionette.lcm_bus import logger_command
from tests_support import controller_running

TALOS = robots.robot("talos")
SOLE_HALF = (0.1025, 0.061)  # TALOS sole box half length, half width [m] (models/talos/talos.xml)


def forward_plan(left, right, count: int, length: float, plan_id: int = 1):
    """``count`` steps of ``length`` forward, right foot first, the last one closing the stance."""
    msg = lcmt_footstep_plan()
    msg.plan_id = plan_id
    msg.first_step_index = 0
    msg.stop_at_end = True
    for k in range(count):
        s = lcmt_footstep()
        s.index = k
        s.is_left = k % 2 == 1
        start = left if s.is_left else right
        s.x = float(start[0] + min(length * (k + 1), length * (count - 1)))
        s.y, s.z, s.yaw = float(start[1]), float(start[2]), float(start[3])
        s.duration, s.double_support, s.step_height = 0.8, 0.2, 0.05
        s.num_via, s.via = 0, []
        msg.steps.append(s)
    msg.num_steps = len(msg.steps)
    return msg


def sole_corners(foot) -> np.ndarray:
    x, y, _, yaw = foot
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[a * SOLE_HALF[0], b * SOLE_HALF[1]] for a in (-1, 1) for b in (-1, 1)])
    return np.array([x, y]) + local @ np.array([[c, s], [-s, c]])


def margin(point, corners) -> float:
    """Signed distance of ``point`` inside the convex hull of ``corners`` (> 0 inside)."""
    hull = ConvexHull(corners)
    # Each facet: normal . x + offset <= 0 inside; the margin is the smallest distance to a facet.
    return float(-np.max(hull.equations[:, :2] @ point + hull.equations[:, 2]))


@pytest.mark.slow
def test_controller_walks_a_plan_and_reports_its_zmp(build_dir, lcm_url, tmp_path):
    statuses: list = []
    states: list = []
    log = tmp_path / "walk.lcmlog"
    logger = subprocess.Popen(
        logger_command(lcm_url, log),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    time.sleep(0.3)  # subscribed before the controller's first message
    try:
        with controller_running(
            build_dir,
            lcm_url,
            tmp_path / "logs",
            "--robot",
            "talos",
            "--scene",
            str(TALOS.mjcf),
            "--speed",
            "0",
            "--camera-rate",
            "0",
        ) as client:
            client.bus.subscribe(channels.WALK_STATUS, lcmt_walk_status, statuses.append)
            client.bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, states.append)
            # A plan before any walking controller is refused with its reason.
            early = forward_plan([0, 0.085, 0, 0], [0, -0.085, 0, 0], 2, 0.1)
            for _ in range(20):  # UDP: resend until the controller has seen one
                client.bus.publish(channels.FOOTSTEP_PLAN, early)
                try:
                    client.wait(
                        lambda c: "has no walk: tasks" in c.status.last_rejection,
                        0.5,
                        "the refused plan",
                    )
                    break
                except TimeoutError:
                    continue
            assert "has no walk: tasks" in client.status.last_rejection

            client.bus.publish(channels.CONTROLLER_SPEC, walking_spec("talos").to_lcm())
            client.wait(
                lambda c: c.status.mode == "running" and c.status.active_controller_id == 1,
                30.0,
                "the walking controller",
            )
            client.wait(lambda c: len(statuses) > 0, 10.0, "WALK_STATUS")
            standing = statuses[-1]
            assert standing.phase == "standing" and standing.current_step_index == -1
            base0 = client.base_position()

            client.bus.publish(
                channels.FOOTSTEP_PLAN,
                forward_plan(standing.left_foot, standing.right_foot, 6, 0.1),
            )
            client.wait(
                lambda c: any(s.current_step_index == 5 for s in statuses), 60.0, "the last step"
            )
            client.wait(lambda c: statuses[-1].phase == "standing", 30.0, "standing again")
            client.wait_time(0.5)
            base = client.base_position()
        time.sleep(0.5)  # the controller's last journal batch reaches the logger
    finally:  # never leave the logger running, whatever failed
        logger.terminate()
        logger.wait(10)

    walked = [s for s in statuses if s.utime > standing.utime]
    assert {s.phase for s in walked} >= {"double_support", "left_swing", "right_swing", "standing"}
    indices = [s.current_step_index for s in walked if s.current_step_index >= 0]
    assert indices == sorted(indices) and indices[-1] == 5, "steps in order, all of them"
    assert abs(base[0] - base0[0] - 0.5) < 0.05, f"walked {base[0] - base0[0]:.3f} m of 0.5"
    assert abs(base[2] - base0[2]) < 0.05, "the base kept its height (no fall)"
    final = walked[-1]
    assert abs(final.left_foot[0] - standing.left_foot[0] - 0.5) < 1e-9
    # The measured ZMP inside the polygon of the soles that carry load (ROBOT_STATE's contact
    # wrenches of the same tick; sole poses from the walk's references, within a few mm of the
    # real ones: 5 mm of tolerance).
    loaded = {}
    for st in states:
        fz = {name: w[2] for name, w in zip(st.contact_frame, st.contact_wrench)}
        loaded[st.utime] = [
            side for side in ("left", "right") if fz.get(f"{side}_sole_link", 0.0) > 10.0
        ]
    margins = []
    for s in walked:
        feet = loaded.get(s.utime)
        if not feet or not np.all(np.isfinite(s.zmp_measured)):
            continue
        corners = np.vstack(
            [sole_corners(s.left_foot if side == "left" else s.right_foot) for side in feet]
        )
        margins.append(margin(np.array(s.zmp_measured), corners))
    print(
        f"measured ZMP margin over {len(margins)} statuses: min {1e3 * min(margins):.1f} mm, "
        f"median {1e3 * np.median(margins):.1f} mm"
    )
    assert len(margins) > 0.8 * len(walked), "statuses and states of the same ticks"
    assert min(margins) > -0.005
    assert np.median(margins) > 0.03

    # Offline replay from the journal: the spec and the plan consumed at their ticks, every
    # recorded command reproduced.
    result = replay_controller(log)
    assert result["problems"] == [] and result["journal_mismatches"] == 0, result["output"]
    assert result["inputs"] >= 2, result["output"]
    assert result["max_difference"] <= 1e-9 and result["ok"], result["output"]
    print(result["output"])
