"""grip_force: the grip force from the jaw contact wrenches of one ROBOT_STATE and the estimate of
eq. 3.11-3.13, on synthetic states whose answer is known in closed form; the holding windows from
step records."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest

from marionette import lcmt_robot_state, robots
from marionette.execution.grip_force import (GripperGeometry, GripForceRecorder, grip_forces,
                                             holding_windows, settled_windows)


@pytest.fixture(scope="module")
def talos():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    return model


def _state(model, q, wrenches: dict[str, np.ndarray], efforts: dict[str, float], utime=0):
    msg = lcmt_robot_state()
    msg.utime = utime
    names = [model.names[j] for j in range(2, model.njoints)]
    msg.num_joints = len(names)
    msg.joint_name = names
    msg.joint_position = [float(q[model.joints[model.getJointId(n)].idx_q]) for n in names]
    msg.joint_velocity = [0.0] * len(names)
    msg.joint_effort = [efforts.get(n, 0.0) for n in names]
    msg.base_position = [float(a) for a in q[:3]]
    x, y, z, w = q[3:7]
    msg.base_quaternion = [float(w), float(x), float(y), float(z)]
    msg.num_contacts = len(wrenches)
    msg.contact_frame = list(wrenches)
    msg.contact_wrench = [list(map(float, w)) for w in wrenches.values()]
    return msg


def test_squeeze_on_both_jaws_reads_its_force_and_the_estimate_its_torque(talos):
    g = GripperGeometry.talos("right", lever_arm=0.085)
    rng = np.random.default_rng(1)
    q = pin.randomConfiguration(talos, np.maximum(talos.lowerPositionLimit, -3), np.minimum(talos.upperPositionLimit, 3))
    data = talos.createData()
    pin.framesForwardKinematics(talos, data, q)
    R = data.oMf[talos.getFrameId("gripper_right_base_link")].rotation
    F = 4.7
    # the plank pushes the double jaw along +y of the gripper base (split over two links), the
    # single jaw along -y; plus a force along the jaws' x (friction) that must not count
    shares = rng.dirichlet([1, 1])
    w = {b: np.zeros(6) for b in g.double_jaw + g.single_jaw}
    w[g.double_jaw[1]][:3] = R @ [0.3, F * shares[0], 0.0]
    w[g.double_jaw[2]][:3] = R @ [0.0, F * shares[1], 0.0]
    w[g.single_jaw[1]][:3] = R @ [-0.3, -F, 0.0]
    tau = -0.4   # closing direction -1: a squeezing motor pushes towards negative q
    est, grip, diff = grip_forces(_state(talos, q, w, {g.joint: tau}), talos, data, g)
    assert grip == pytest.approx(F, abs=1e-9)
    assert diff == pytest.approx(0.0, abs=1e-9)
    assert est == pytest.approx(-1.0 * tau / 0.085)


def test_without_jaw_wrenches_the_contact_is_unknown(talos):
    g = GripperGeometry.talos("left", lever_arm=0.085)
    q = pin.neutral(talos)
    est, grip, _ = grip_forces(_state(talos, q, {}, {g.joint: 0.0}), talos, talos.createData(), g)
    assert est == 0.0 and np.isnan(grip)


def test_holding_windows_run_from_the_first_holding_step_to_the_release():
    steps = [SimpleNamespace(index=i, grasps=grasps) for i, grasps in
             enumerate([{}, {"g": "h"}, {"g": "h"}, {}, {"g": "h"}])]
    records = [SimpleNamespace(index=i, utime_start=int(1e6 * (i + 1)), utime_end=int(1e6 * (i + 1.9)))
               for i in range(5)]
    assert np.allclose(holding_windows(steps, records, "g"), [(2.0, 4.0), (5.0, 5.9)])
    assert holding_windows(steps, records, "other") == []


def test_settled_windows_start_a_second_after_the_estimate_reaches_the_threshold(talos):
    rec = GripForceRecorder(talos, {"g": GripperGeometry.talos("right", 0.085)})
    rec.t = list(np.arange(0.0, 10.0, 0.1))
    rec.estimate["g"] = [0.0 if t < 3.05 else 5.0 for t in rec.t]
    ((a, b),) = settled_windows(rec, "g", [(2.0, 8.0), (8.5, 9.0)], threshold=4.0)
    assert a == pytest.approx(4.1) and b == 8.0
