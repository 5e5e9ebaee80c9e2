"""grip_force: the grip force from the jaw contact wrenches of one ROBOT_STATE and the estimate of
eq. 3.11-3.13, on synthetic states whose answer is known in closed form (the UR10's parallel
gripper with its robot.yaml parameters, TALOS' two-jaw gripper); the holding windows from step
records."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest

from marionette import lcmt_robot_state, robots
from marionette.execution.grip_force import (
    GripForceRecorder,
    GripperGeometry,
    grip_forces,
    holding_windows,
    settled_windows,
)


@pytest.fixture(scope="module")
def ur10():
    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    return model


@pytest.fixture(scope="module")
def talos():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    return model


def _state(model, q, wrenches: dict[str, np.ndarray], efforts: dict[str, float], utime=0):
    msg = lcmt_robot_state()
    msg.utime = utime
    first = 2 if model.joints[1].nq == 7 else 1  # after a free-flyer root
    names = [model.names[j] for j in range(first, model.njoints)]
    msg.num_joints = len(names)
    msg.joint_name = names
    msg.joint_position = [float(q[model.joints[model.getJointId(n)].idx_q]) for n in names]
    msg.joint_velocity = [0.0] * len(names)
    msg.joint_effort = [efforts.get(n, 0.0) for n in names]
    if first == 2:
        msg.base_position = [float(a) for a in q[:3]]
        x, y, z, w = q[3:7]
        msg.base_quaternion = [float(w), float(x), float(y), float(z)]
    else:
        msg.base_position, msg.base_quaternion = [0.0] * 3, [1.0, 0.0, 0.0, 0.0]
    msg.num_contacts = len(wrenches)
    msg.contact_frame = list(wrenches)
    msg.contact_wrench = [list(map(float, w)) for w in wrenches.values()]
    return msg


def _random_q(model, seed):
    np.random.seed(seed)
    return pin.randomConfiguration(
        model, np.maximum(model.lowerPositionLimit, -3), np.minimum(model.upperPositionLimit, 3)
    )


def test_parallel_gripper_reads_the_squeeze_and_half_the_motor_force(ur10):
    (gripper,) = [g for g in robots.semantics("ur10").grippers if g.joint]
    g = GripperGeometry.of("ur10", gripper.name, gripper.admittance, closing_direction=1.0)
    assert (g.lever_arm, g.torque_per_effort) == (1.0, 0.5)
    q = _random_q(ur10, 3)
    data = ur10.createData()
    pin.framesForwardKinematics(ur10, data, q)
    R = data.oMf[ur10.getFrameId("gripper_link")].rotation
    F = 5.2
    # The box pushes the left finger along +y of gripper_link and the right one along -y, plus
    # friction along the fingers (z) that must not count.
    w = {
        "finger_left_link": np.r_[R @ [0.0, F, 1.5], 0, 0, 0],
        "finger_right_link": np.r_[R @ [0.0, -F, 1.5], 0, 0, 0],
    }
    est, grip, diff = grip_forces(_state(ur10, q, w, {"finger_joint": 2 * F}), ur10, data, g)
    assert grip == pytest.approx(F, abs=1e-9)
    assert diff == pytest.approx(0.0, abs=1e-9)
    assert est == pytest.approx(F)  # a squeezing motor (+q closes) pushes with 2F


@pytest.mark.parametrize("hand", ["left", "right"])
def test_talos_jaws_read_their_squeeze(talos, hand):
    """The +y jaw of each hand's gripper frame (the right hand's frame is the left's turned
    about its approach axis: its +y jaw is the single one) pushes along +y, the other along -y."""
    g = GripperGeometry.of(
        "talos", f"talos/{hand}_gripper", {"lever_arm": 0.085}, closing_direction=-1.0
    )
    q = _random_q(talos, 1)
    data = talos.createData()
    pin.framesForwardKinematics(talos, data, q)
    R = data.oMf[talos.getFrameId(g.base_link)].rotation
    y = R @ g.y_in_link  # the closing axis in the world
    x = R @ np.cross(g.y_in_link, [0.0, 0.0, 1.0])  # along the fingers: must not count
    F = 4.7
    w = {b: np.zeros(6) for b in g.plus_jaw + g.minus_jaw}
    w[g.plus_jaw[1]][:3] = 0.3 * x + 0.4 * F * y
    w[g.plus_jaw[2]][:3] = 0.6 * F * y
    w[g.minus_jaw[1]][:3] = -0.3 * x - F * y
    tau = -0.4  # closing direction -1: a squeezing motor pushes towards negative q
    est, grip, diff = grip_forces(_state(talos, q, w, {g.joint: tau}), talos, data, g)
    assert grip == pytest.approx(F, abs=1e-9)
    assert diff == pytest.approx(0.0, abs=1e-9)
    assert est == pytest.approx(-1.0 * tau / 0.085)


def test_without_jaw_wrenches_the_contact_is_unknown(ur10):
    g = GripperGeometry.of("ur10", "ur10/gripper", {}, closing_direction=1.0)
    est, grip, _ = grip_forces(
        _state(ur10, pin.neutral(ur10), {}, {g.joint: 0.0}), ur10, ur10.createData(), g
    )
    assert est == 0.0 and np.isnan(grip)


def test_holding_windows_run_from_the_first_holding_step_to_the_release():
    steps = [
        SimpleNamespace(index=i, grasps=grasps)
        for i, grasps in enumerate([{}, {"g": "h"}, {"g": "h"}, {}, {"g": "h"}])
    ]
    records = [
        SimpleNamespace(index=i, utime_start=int(1e6 * (i + 1)), utime_end=int(1e6 * (i + 1.9)))
        for i in range(5)
    ]
    assert np.allclose(holding_windows(steps, records, "g"), [(2.0, 4.0), (5.0, 5.9)])
    assert holding_windows(steps, records, "other") == []
    # The trial stopped in step 2 (started, never ended): the hold is judged up to the stop.
    stopped = [*records[:2], SimpleNamespace(index=2, utime_start=3_000_000, utime_end=None)]
    assert np.allclose(holding_windows(steps, stopped, "g", t_stop=7.5), [(2.0, 7.5)])
    assert np.allclose(holding_windows(steps, stopped, "g"), [(2.0, 3.0)])


def test_settled_windows_start_a_second_after_the_estimate_reaches_the_threshold(ur10):
    rec = GripForceRecorder(ur10, {"g": GripperGeometry.of("ur10", "ur10/gripper", {}, 1.0)})
    rec.t = list(np.arange(0.0, 10.0, 0.1))
    rec.estimate["g"] = [0.0 if t < 3.05 else 5.0 for t in rec.t]
    rec.contact["g"] = [0.0 if t < 3.05 else 5.5 for t in rec.t]
    ((a, b),) = settled_windows(rec, "g", [(2.0, 8.0), (8.5, 9.0)], threshold=4.0)
    assert a == pytest.approx(4.1) and b == 8.0
    s = rec.holding_summary("g", a, b, target=5.0)
    assert s["contact_median_n"] == pytest.approx(5.5) and s["contact_within_tolerance"] == 1.0
    assert s["estimate_minus_contact_median_n"] == pytest.approx(-0.5)
