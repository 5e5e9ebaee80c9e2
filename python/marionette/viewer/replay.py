"""``marionette replay LOG --view``: a recorded run played in the browser viewer, its report
re-plotted from the log.

The LCM log (e.g. a demo's ``run.lcmlog``) is played in log order at ``speed`` times
the recorded pace (0: as fast as possible) into a :class:`.scene.ViewerScene` (its scene: the one
the ``report.json`` beside the log names); the robot is redrawn at most ``rate_hz`` times per
second of playback. The report's task-error plot
(:func:`marionette.scenarios.plan_and_execute_report._plots`) is rebuilt from the log alone: the
steps from the supervisor's decisions (SUPERVISOR_DECISION: controller id, swap and
reference-start ticks), the error traces from CONTROLLER_STATUS, the tasks and their references
(split by unit) from CONTROLLER_SPEC and TASK_REFERENCE, the executed motion from ROBOT_STATE and
SIM_OBJECT_POSES.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

import lcm
from marionette import (
    channels,
    lcmt_controller_spec,
    lcmt_controller_status,
    lcmt_footstep_plan,
    lcmt_object_poses,
    lcmt_robot_state,
    lcmt_supervisor_decision,
    lcmt_supervisor_state,
    lcmt_task_reference,
)

DRAWN = {
    channels.ROBOT_STATE: lcmt_robot_state,
    channels.SIM_OBJECT_POSES: lcmt_object_poses,
    channels.OBJECT_POSES: lcmt_object_poses,
    channels.FOOTSTEP_PLAN: lcmt_footstep_plan,
    channels.SUPERVISOR_STATE: lcmt_supervisor_state,
}


class ReplayError(ValueError):
    """The log cannot be played (missing, no ROBOT_STATE, undecodable message)."""


@dataclass
class PlaybackStats:
    messages: int = 0  # messages given to the scene
    robot_frames: int = 0  # robot redraws
    log_duration_s: float = 0.0  # first to last message of the log
    wall_s: float = 0.0
    counts: dict[str, int] = field(default_factory=dict)


def log_robot(log: Path) -> str:
    """The robot of a recorded run (its first ROBOT_STATE's robot_name)."""
    for ev in _events(log):
        if ev.channel == channels.ROBOT_STATE:
            return lcmt_robot_state.decode(ev.data).robot_name
    raise ReplayError(f"{log} holds no {channels.ROBOT_STATE} message: nothing to show")


def run_scene(log: Path) -> Path | None:
    """The MJCF scene of a demo's recorded run: the ``scene`` its report.json beside the log
    names (relative to the repository, or absolute); None without a report or a scene in it."""
    report = Path(log).parent / "report.json"
    if not report.is_file():
        return None
    import marionette

    scene = json.loads(report.read_text()).get("scene")
    if not scene:
        return None
    return Path(scene) if Path(scene).is_absolute() else marionette.REPO_ROOT / scene


def play(
    log: Path,
    scene: Any,
    speed: float = 1.0,
    rate_hz: float = 20.0,
    until_s: float | None = None,
    sleep: Callable[[float], None] = time.sleep,
) -> PlaybackStats:
    """Feeds the drawn channels of ``log`` to ``scene`` in log order, paced at ``speed`` x the
    recorded time (0: unpaced), up to ``until_s`` seconds of log time (None: all)."""
    if speed < 0:
        raise ReplayError(f"speed must be >= 0, got {speed}")
    if rate_hz <= 0:
        raise ReplayError(f"rate_hz must be > 0, got {rate_hz}")
    stats = PlaybackStats()
    handlers = {
        channels.ROBOT_STATE: scene.on_robot_state,
        channels.SIM_OBJECT_POSES: scene.on_object_poses,
        channels.OBJECT_POSES: scene.on_object_poses,
        channels.FOOTSTEP_PLAN: scene.on_footstep_plan,
        channels.SUPERVISOR_STATE: scene.on_supervisor_state,
    }
    # Robot frames at most rate_hz per second of playback: every max(speed, 1)/rate_hz s of log.
    frame_us = 1e6 * max(speed, 1.0) / rate_hz
    wall0 = time.monotonic()
    t0 = last_frame = None
    pending = None
    t_log = 0
    for ev in _events(log):
        lcm_type = DRAWN.get(ev.channel)
        if lcm_type is None:
            continue
        t0 = ev.timestamp if t0 is None else t0
        t_log = ev.timestamp - t0
        if until_s is not None and t_log > until_s * 1e6:
            break
        if speed > 0:
            ahead = t_log / speed * 1e-6 - (time.monotonic() - wall0)
            if ahead > 0:
                sleep(ahead)
        try:
            msg = lcm_type.decode(ev.data)
        except ValueError as e:
            raise ReplayError(
                f"{log}: cannot decode {ev.channel} at {ev.timestamp} us: {e}"
            ) from None
        stats.counts[ev.channel] = stats.counts.get(ev.channel, 0) + 1
        if ev.channel == channels.ROBOT_STATE:
            pending = msg
            if last_frame is not None and ev.timestamp - last_frame < frame_us:
                continue
            last_frame, pending = ev.timestamp, None
            stats.robot_frames += 1
        handlers[ev.channel](msg)
        stats.messages += 1
    if pending is not None:  # the last pose of the run is always shown
        scene.on_robot_state(pending)
        stats.robot_frames += 1
        stats.messages += 1
    stats.log_duration_s = t_log * 1e-6
    stats.wall_s = time.monotonic() - wall0
    return stats


def replot_report(log: Path, out_dir: Path, every: int = 5) -> list[Path]:
    """Re-plots the demo report's plots that the log alone determines into ``out_dir``
    (task errors per step; CoM for humanoids); returns the files written."""
    from marionette import robots
    from marionette.control.client import configuration_from_state
    from marionette.control.spec import SpecError, TaskSpec
    from marionette.scenarios import plan_and_execute_report as report
    from marionette.scenarios.task_error_plot import StepTasks

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    decisions, statuses, states, objects, chunks = [], [], [], [], []
    tasks: dict[int, dict[str, TaskSpec]] = {}
    latest_objects: dict[str, np.ndarray] = {}
    robot = None
    model = None
    k = 0
    for ev in _events(log):
        if ev.channel == channels.SUPERVISOR_DECISION:
            decisions.append(lcmt_supervisor_decision.decode(ev.data))
        elif ev.channel == channels.CONTROLLER_STATUS:
            statuses.append(lcmt_controller_status.decode(ev.data))
        elif ev.channel == channels.CONTROLLER_SPEC:
            spec = lcmt_controller_spec.decode(ev.data)
            try:
                tasks[spec.controller_id] = {t.name: TaskSpec.from_lcm(t) for t in spec.tasks}
            except SpecError:  # refused by the controller too: its errors stay unit-less
                pass
        elif ev.channel == channels.TASK_REFERENCE:
            chunks.append(lcmt_task_reference.decode(ev.data))
        elif ev.channel == channels.SIM_OBJECT_POSES:
            m = lcmt_object_poses.decode(ev.data)
            latest_objects = {
                o.object_name: np.array([*o.position_world, *o.quaternion_world]) for o in m.objects
            }
        elif ev.channel == channels.ROBOT_STATE:
            k += 1
            if k % every:
                continue
            m = lcmt_robot_state.decode(ev.data)
            if model is None:
                robot = m.robot_name
                model, _ = robots.load_pinocchio(robot, with_collision=False)
            states.append((m.utime, configuration_from_state(model, m)))
            objects.append(dict(latest_objects))
    if model is None:
        raise ReplayError(f"{log} holds no {channels.ROBOT_STATE} message: nothing to plot")
    if not decisions:
        raise ReplayError(
            f"{log} holds no {channels.SUPERVISOR_DECISION} message: the steps are unknown"
        )
    records = _records(decisions, statuses)
    recorder = SimpleNamespace(
        utimes=[u for u, _ in states], q=[q for _, q in states], objects=objects
    )
    name = (
        json.loads((Path(log).parent / "report.json").read_text()).get("scenario", "run")
        if (Path(log).parent / "report.json").is_file()
        else "run"
    )
    scenario = SimpleNamespace(name=f"{name} (replayed)", object_name="", feet=())
    # No planned trajectories in the log: the planned-vs-executed plots are left to the live report.
    supervisor = SimpleNamespace(trajectories={}, robot_map=SimpleNamespace(robot=robot))
    references = _references(chunks)
    task_steps = [
        StepTasks(
            r.error_trace, tasks.get(r.controller_id, {}), references.get(r.controller_id, {})
        )
        for r in records
    ]
    return report._plots(
        out_dir, scenario, supervisor, SimpleNamespace(records=records), recorder, model, task_steps
    )


def _references(chunks: list[Any]) -> dict[int, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """The references streamed in TASK_REFERENCE chunks, by controller id and task: (t [s], values
    (N x k)); a chunk overrides the samples of earlier ones from its start on, as in the
    controller."""
    samples: dict[tuple[int, str], list[tuple[np.ndarray, np.ndarray]]] = {}
    for c in chunks:
        if c.num_samples == 0:
            continue
        t = (c.utime + c.dt_us * np.arange(c.num_samples)) * 1e-6
        parts = samples.setdefault((c.controller_id, c.task_name), [])
        while parts and len(parts[-1][0]) and parts[-1][0][-1] >= t[0]:
            pt, pv = parts.pop()
            if pt[0] < t[0]:
                parts.append((pt[pt < t[0]], pv[pt < t[0]]))
                break
        parts.append((t, np.array(c.value, dtype=float).reshape(c.num_samples, c.value_size)))
    out: dict[int, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    for (cid, name), parts in samples.items():
        t = np.concatenate([pt for pt, _ in parts])
        if len(t):
            out.setdefault(cid, {})[name] = (t, np.vstack([pv for _, pv in parts]))
    return out


def _records(decisions: list[Any], statuses: list[Any]) -> list[Any]:
    """Per-step records (index, swap tick, reference start, error trace) from the decisions."""
    records = []
    for d in sorted(decisions, key=lambda m: m.seq):
        ins = dict(zip(d.input_name, d.input_value))
        if d.event == "step_started":
            records.append(
                SimpleNamespace(
                    index=d.step_index,
                    controller_id=int(ins["controller_id"]),
                    utime_start=0,
                    utime_reference_start=0,
                    error_trace=[],
                )
            )
        elif records and d.event == "switch_accepted":
            records[-1].utime_start = d.utime
        elif records and d.event == "reference_started":
            records[-1].utime_reference_start = int(ins["start_utime"])
    by_id = {r.controller_id: r for r in records}
    for st in statuses:
        r = by_id.get(st.active_controller_id)
        if r is not None and st.utime >= r.utime_start > 0:
            r.error_trace.append((st.utime, dict(zip(st.task_name, st.task_error_norm))))
    return records


def _events(log: Path):
    log = Path(log)
    if not log.is_file():
        raise FileNotFoundError(f"no LCM log at {log}")
    try:
        return lcm.EventLog(str(log), "r")
    except (OSError, ValueError) as e:
        raise ReplayError(f"{log} is not an LCM log: {e}") from None


def serve_replay(
    log: Path,
    speed: float,
    scene_path: Path | None,
    out_dir: Path,
    hold: bool,
    print_: Callable[[str], None] = print,
) -> int:
    """``marionette replay LOG --view``: serves the page, plays the log, re-plots the report;
    with ``hold`` keeps serving until Ctrl-C. Returns the exit code."""
    from marionette.viewer.node import MeshcatServer
    from marionette.viewer.scene import ViewerScene

    robot = log_robot(log)
    scene_path = scene_path or run_scene(log)
    server = MeshcatServer()
    try:
        scene = ViewerScene(server.visualizer(), robot, scene_path)
        print_(
            f"marionette replay: open {server.web_url} ({robot}, playing at {speed}x; Ctrl-C stops)"
        )
        stats = play(log, scene, speed)
        print_(
            f"played {stats.messages} messages ({stats.robot_frames} robot frames) of "
            f"{stats.log_duration_s:.1f} s of log in {stats.wall_s:.1f} s"
        )
        plots = replot_report(log, out_dir)
        print_("report re-plotted from the log: " + ", ".join(str(p) for p in plots))
        while hold:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0
