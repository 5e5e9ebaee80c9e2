"""The grip monitor: fingers that reach their closed position hold nothing (grip_monitor.py).

Reference: the rule written out here on hand-made robot states — closure = (q - open) /
(closed - open) past 0.9 for 50 ms of controller time — at both state rates a controller
publishes (1 kHz paced, 5 Hz unpaced)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from marionette.execution.factory import GripperJoint
from marionette.execution.grip_monitor import GripMonitor, GripMonitorOptions

UR10 = SimpleNamespace(name="ur10/gripper", joint=GripperJoint("finger_joint", 0.0, 0.04))


def _step(grasps):
    return SimpleNamespace(grasps=grasps)


def _state(utime_us, finger):
    return SimpleNamespace(
        utime=int(utime_us),
        joint_name=["wrist_3_joint", "finger_joint"],
        joint_position=[0.3, finger],
    )


@pytest.mark.parametrize("period_us", [1000, 200_000])
def test_fingers_closed_on_nothing_are_reported_after_the_duration(period_us):
    monitor = GripMonitor({UR10.name: UR10.joint}, GripMonitorOptions(min_duration_s=0.05))
    monitor.begin_step(_step({UR10.name: "box/top"}))
    # Closing on the box: the fingers stop at 0.0157 (39 % of the stroke).
    assert all(monitor.on_state(_state(k * period_us, 0.0157)) is None for k in range(200))
    # The box is gone: the fingers travel to the closed end (>= 0.036, 90 % of the stroke).
    t0 = 200 * period_us
    fired = None
    k = 0
    while fired is None:
        fired = monitor.on_state(_state(t0 + k * period_us, 0.0401))
        k += 1
    assert (k - 1) * period_us * 1e-6 == pytest.approx(max(0.05, period_us * 1e-6), abs=1e-3)
    assert fired.gripper == UR10.name and fired.handle == "box/top"
    assert "holds nothing" in fired.describe() and "box/top" in fired.describe()
    assert monitor.on_state(_state(t0 + k * period_us, 0.0401)) is None  # once per step


def test_only_held_grippers_are_watched_and_a_glitch_is_not_a_loss():
    monitor = GripMonitor({UR10.name: UR10.joint})
    monitor.begin_step(_step({}))  # the gripper approaches or opens: closed is not a failure
    assert all(monitor.on_state(_state(k * 1000, 0.04)) is None for k in range(500))
    monitor.begin_step(_step({UR10.name: "box/top"}))
    # 40 ms at the closed end, then back on the box: not a loss.
    states = [0.04] * 40 + [0.016] * 10 + [0.04] * 40
    assert all(
        monitor.on_state(_state(1_000_000 + k * 1000, q)) is None for k, q in enumerate(states)
    )
    # A timer runs on across steps that keep holding, and starts again after a release.
    monitor.begin_step(_step({UR10.name: "box/top"}))
    assert monitor.on_state(_state(1_000_000 + 100 * 1000, 0.04)) is not None


def test_the_grippers_watched_are_the_plans_admittance_grippers():
    """What the demo watches (FactoryContext.gripper_joints): the plan's grippers with a finger
    joint, robot.yaml's positions; the UR10's drill has no fingers."""
    from marionette import robots
    from marionette.execution.factory import context_from_plan

    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    doc = {"graph": {}, "problem": {"grippers": ["ur10/gripper", "ur10/drill"], "handles": {}}}
    watched = context_from_plan(doc, "ur10", model, gripper_admittance=True).gripper_joints
    assert list(watched) == ["ur10/gripper"]
    g = watched["ur10/gripper"]
    assert (g.joint, g.open_position, g.closed_position) == ("finger_joint", 0.0, 0.04)
    assert g.closure(0.036) == pytest.approx(0.9)
