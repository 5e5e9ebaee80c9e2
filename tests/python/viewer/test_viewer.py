"""The browser viewer, loaded in headless Chromium: the page shows the robot, changes
as the robot moves, shows the FSM text; `marionette demo --view` served it during a run;
`marionette replay LOG --view` plays a recorded run and re-plots its report from the log."""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import pytest

import lcm
import marionette
from marionette import channels, lcmt_robot_state, lcmt_supervisor_state, robots
from marionette.execution.decision_replay import decision_record, read_decision_log
from marionette.lcm_bus import LcmBus
from marionette.processes import ProcessGroup
from marionette.viewer.node import MeshcatServer, start_viewer
from marionette.viewer.replay import play, replot_report, run_scene
from marionette.viewer.scene import ViewerScene
from marionette.viewer.screenshot import screenshot

SCENE = marionette.MODELS_DIR / "scenes" / "ur10_box.xml"


def changed(a: np.ndarray, b: np.ndarray, threshold: int = 40) -> np.ndarray:
    """Pixels whose colour differs by more than ``threshold`` (sum over RGB)."""
    return np.abs(a.astype(int) - b.astype(int)).sum(-1) > threshold


def ur10_state(q: np.ndarray, model) -> lcmt_robot_state:
    names = [model.names[j] for j in range(1, model.njoints)]
    m = lcmt_robot_state()
    m.robot_name, m.num_joints, m.joint_name = "ur10", len(names), names
    m.joint_position, m.joint_velocity, m.joint_effort = list(q), [0.0] * len(q), [0.0] * len(q)
    m.base_quaternion = [1.0, 0.0, 0.0, 0.0]
    return m


@pytest.mark.slow
def test_viewer_process_shows_the_robot_moving_and_the_fsm_state(lcm_url, tmp_path):
    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    q_a = robots.reference_configuration("ur10", model)
    q_b = q_a.copy()
    q_b[0] += 1.2  # shoulder pan: the whole arm swings sideways
    with ProcessGroup(lcm_url, tmp_path / "logs") as group, LcmBus(lcm_url) as bus:
        url = start_viewer(group, "ur10", SCENE, log=lambda m: None)
        empty = screenshot(url, tmp_path / "empty.png")
        bus.publish(channels.ROBOT_STATE, ur10_state(q_a, model))
        time.sleep(1.0)
        shot_a = screenshot(url, tmp_path / "a.png")
        st = lcmt_supervisor_state()
        st.plan_name, st.state, st.step_index, st.num_steps, st.status = (
            "ur10_box",
            "grasp",
            1,
            8,
            "running",
        )
        bus.publish(channels.SUPERVISOR_STATE, st)
        bus.publish(channels.ROBOT_STATE, ur10_state(q_b, model))
        time.sleep(1.0)
        shot_b = screenshot(url, tmp_path / "b.png")
        group.check_alive()
    h, w, _ = empty.shape
    # Not blank: the sky gradient and the grid (a blank or failed WebGL page is one colour).
    assert empty.std() > 20
    # The robot appears with the first ROBOT_STATE (hidden before): light-grey mesh pixels.
    robot_px = changed(empty, shot_a)
    grey = (np.ptp(shot_a.astype(int), axis=-1) < 25) & (shot_a.min(-1) > 120)
    assert (robot_px & grey).sum() > 0.005 * h * w, (robot_px & grey).sum()
    # It moves: the arm's pixels change between the two configurations.
    moved = changed(shot_a, shot_b)
    assert moved.sum() > 0.002 * h * w
    # The FSM panel (light grey (240, 240, 240), below meshcat's 20-pixel control bar) shows the
    # new state: its dark text pixels changed.
    # (unlit: exactly 240, unlike the lit grey meshes).
    panel = np.all(np.abs(shot_b.astype(int) - 240) <= 2, axis=-1)
    panel[:25] = False
    rows, cols = np.nonzero(panel)
    assert len(rows) > 1500, "no FSM panel"
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    text_a, text_b = shot_a[box].max(-1) < 200, shot_b[box].max(-1) < 200
    assert text_a.sum() > 30 and text_b.sum() > 30 and (text_a != text_b).sum() > 50


def test_demo_view_served_the_run_and_stopped_with_it(ur10_box_run):
    report = json.loads((ur10_box_run / "report.json").read_text())
    assert report["success"] and report["viewer_url"].startswith("http://127.0.0.1:")
    viewer_log = (ur10_box_run / "logs" / "viewer.log").read_text()
    assert "marionette view: open " + report["viewer_url"] in viewer_log
    assert "Traceback" not in viewer_log


@pytest.mark.slow
def test_replay_view_plays_the_recorded_run_and_replots_it(ur10_box_run, tmp_path):
    log = ur10_box_run / "run.lcmlog"
    report = json.loads((ur10_box_run / "report.json").read_text())
    assert run_scene(log) == SCENE  # from report.json: no scenario registry needed
    server = MeshcatServer()
    try:
        scene = ViewerScene(server.visualizer(), "ur10", run_scene(log))
        early = play(log, scene, speed=0.0, until_s=2.0)
        shot_early = screenshot(server.web_url, tmp_path / "early.png")
        full = play(log, scene, speed=0.0)
        shot_end = screenshot(server.web_url, tmp_path / "end.png")
    finally:
        server.close()
    # every robot state of the log played (counted from the log itself: a run's length depends
    # on its plan)
    recorded = sum(
        1 for event in lcm.EventLog(str(log), "r") if event.channel == channels.ROBOT_STATE
    )
    assert early.robot_frames >= 1 and full.counts[channels.ROBOT_STATE] == recorded > 100
    assert full.counts[channels.SUPERVISOR_STATE] > 0 and "done" in scene.fsm_text
    assert (
        scene._objects.get("box") is not None and scene._objects.get("table") is not None
    )  # box: SIM_OBJECT_POSES; table: the scene YAML
    h, w, _ = shot_end.shape
    assert changed(shot_early, shot_end).sum() > 0.002 * h * w  # the arm and the box moved
    plots = replot_report(log, tmp_path / "replot")
    assert [p.name for p in plots] == ["task_errors.png"] and plots[0].stat().st_size > 10_000
    decisions, _ = read_decision_log(decision_record(log))
    ids = [int(d.inputs["controller_id"]) for d in decisions if d.event == "step_started"]
    assert ids == [s["controller_id"] for s in report["steps"]]


def test_the_scene_of_a_recorded_run_comes_from_its_report_alone(tmp_path, monkeypatch):
    """``scene`` in report.json, relative to the repository or absolute; no report or no scene:
    None. The scenario registry is never imported (a report is read without the code that ran
    it)."""
    import sys

    monkeypatch.setitem(sys.modules, "marionette.scenarios", None)  # importing it would fail
    log = tmp_path / "run.lcmlog"
    assert run_scene(log) is None
    report = tmp_path / "report.json"
    report.write_text(json.dumps({"scenario": "gone-since", "scene": "models/scenes/ur10_box.xml"}))
    assert run_scene(log) == SCENE
    elsewhere = tmp_path / "scene.xml"
    report.write_text(json.dumps({"scenario": "gone-since", "scene": str(elsewhere)}))
    assert run_scene(log) == elsewhere
    report.write_text(json.dumps({"scenario": "ur10-box"}))  # a report from before the scene
    assert run_scene(log) is None


def test_replay_view_rejects_bad_input(tmp_path):
    import subprocess

    missing = subprocess.run(
        [
            sys.executable,
            "-m",
            "marionette.cli",
            "replay",
            str(tmp_path / "nope.lcmlog"),
            "--view",
            "--no-hold",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert missing.returncode == 1 and "no LCM log at" in missing.stderr
    with pytest.raises(ValueError, match="speed must be >= 0"):
        play(tmp_path / "x.lcmlog", None, speed=-1.0)


@pytest.mark.slow
def test_footstep_plan_is_drawn_as_soles(tmp_path):
    """FOOTSTEP_PLAN -> one sole box per step: the two right feet appear as two orange patches,
    the left foot as one blue patch (counted as connected regions of new pixels)."""
    from scipy import ndimage

    from marionette import lcmt_footstep, lcmt_footstep_plan

    def orange(img: np.ndarray) -> np.ndarray:
        r, g, b = (img[..., k].astype(int) for k in range(3))
        return (r > 150) & (r - b > 80) & (g < r - 30)

    def blue(img: np.ndarray) -> np.ndarray:
        r, g, b = (img[..., k].astype(int) for k in range(3))
        return (b > 150) & (b - r > 100) & (b - g > 60)

    def patches(mask: np.ndarray) -> list[int]:
        """Pixel counts of the connected regions of at least 20 pixels (soles, not edges)."""
        labels, _ = ndimage.label(mask)
        sizes = np.bincount(labels.ravel())[1:]
        return sorted(int(s) for s in sizes if s >= 20)

    server = MeshcatServer()
    try:
        scene = ViewerScene(server.visualizer(), "talos", None)
        before = screenshot(server.web_url, tmp_path / "before.png")
        plan = lcmt_footstep_plan()
        for i, (x, y) in enumerate([(0.2, -0.1), (0.4, 0.1), (0.6, -0.1)]):
            s = lcmt_footstep()
            s.index, s.is_left, s.x, s.y, s.z, s.yaw = i, y > 0, x, y, 0.0, 0.0
            plan.steps.append(s)
        plan.num_steps = len(plan.steps)
        scene.on_footstep_plan(plan)
        after = screenshot(server.web_url, tmp_path / "after.png")
    finally:
        server.close()
    assert scene.footsteps == 3
    # (the world triad's red x axis has a few orange-ish pixels already: only new pixels count)
    assert len(patches(orange(after) & ~orange(before))) == 2
    assert len(patches(blue(after) & ~blue(before))) == 1
