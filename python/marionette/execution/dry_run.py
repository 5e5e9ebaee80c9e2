"""The dry run: a plan's generated controllers played on the plan before anything moves, and the
plan refused when execution would fail.

Two parts, on the references the supervisor will stream (:meth:`Supervisor.prepare`):

1. **Singularities along each step** (Pinocchio, no controller). Every ``sample_period_s`` of a
   step's references, each priority level's Jacobian with the levels above projected out
   (:func:`factory.level_conditioning`, the strict hierarchy the controller solves): a level whose
   smallest needed singular value drops below ``singular_threshold`` — the solver's damping
   threshold (``HierarchyOptions::damping_threshold``), below which the level is damped and its
   task no longer tracked — crosses a singularity there. The start-only rank check of
   :func:`factory.check_specs` misses a step that starts and ends regular and crosses one.
2. **Played** (:func:`play`): ``marionette-controller`` on the kinematic backend (no physics: the
   controllers, their start and end checks, their velocity limits) paced at ``speed`` times real
   time (4: unpaced, the controller outruns the Python streamer on a loaded machine and the
   watchdog holds it — a streaming failure, not the plan's; a starved run is played again at real
   time) on a private LCM URL, driven by the same :class:`~.supervisor.Supervisor` with the same
   controllers and references (no camera: the visual corrections stay at identity). Refused
   switches are the controller's own start check; an end check that fails within the converge
   timeout is a task
   that does not converge; and every joint the posture follows is compared with its streamed
   reference at the same controller time: one farther than ``branch_tolerance`` left the planned
   IK branch (a 6-DoF arm flipping its elbow through a singularity, its gripper on its pose:
   only the joints show it).

Reported beside them, not a reason to refuse: each step's **static load**
(:mod:`.static_load`), the largest gravity torque a joint bears along the step — its links and
what its grippers carry — as a fraction of its effort limit.

The verdict is per step (:class:`StepVerdict`); :func:`dry_run` returns them with the plan's
(:class:`DryRun`), which a scenario writes to its report and refuses the plan on.
"""

from __future__ import annotations

import dataclasses
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

import marionette
from marionette import channels, lcmt_robot_state, robots
from marionette.control.client import ControllerClient, configuration_from_state
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.factory import level_conditioning
from marionette.execution.plan_steps import PlanRobotMap, Step
from marionette.execution.references import StepTrajectory, minimum_jerk, velocity_limits
from marionette.execution.static_load import step_static_load
from marionette.robots import controller_robot_argument

# The controller's hierarchy damps a level whose smallest pivot is below this (hierarchy.h).
SINGULAR_THRESHOLD = 0.02


@dataclass(frozen=True)
class DryRunOptions:
    """``singular_threshold``: smallest singular value a level may need (its units: m or rad per
    rad); ``branch_tolerance`` [rad]: a joint this far from its reference left the plan's IK
    branch; ``speed``: the controller's pacing (0: as fast as it computes; a run starved of
    references is played again at ``fallback_speed``)."""

    singular_threshold: float = SINGULAR_THRESHOLD
    sample_period_s: float = 0.05
    branch_tolerance: float = 0.25
    speed: float = 4.0
    fallback_speed: float = 1.0
    ready_timeout_s: float = 60.0


@dataclass
class StepVerdict:
    """What the dry run found in one step; ``reasons`` empty: the step passes."""

    index: int
    transition: str
    played: bool = False
    min_singular_value: float = float("inf")  # over the step's samples and levels
    singular_level: str = ""  # the level (its tasks) and the time where it is reached
    switch: str = ""  # "accepted", "accepted after N retries", or why it was refused
    converged: bool | None = None  # the end check passed (None: not played)
    max_joint_deviation: float = 0.0  # [rad] executed vs streamed reference
    deviation_joint: str = ""
    controller_s: float = 0.0
    static_load: float | None = None  # the largest |gravity torque| / effort limit
    static_load_joint: str = ""
    reasons: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.reasons

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["ok"] = self.ok
        if not np.isfinite(self.min_singular_value):
            d["min_singular_value"] = None
        return d


@dataclass
class DryRun:
    """The dry run's verdict: ``ok`` when every step passes; ``reason`` the first problem."""

    backend: str
    steps: list[StepVerdict]
    wall_s: float = 0.0
    controller_s: float = 0.0
    supervisor: str = ""  # the played supervisor's end state and reason
    completed: bool = False  # the played supervisor reached done
    speeds: tuple[float, ...] = ()  # the controller pacings played (a starved one, then real time)

    @property
    def ok(self) -> bool:
        return self.completed and all(s.ok for s in self.steps)

    @property
    def reason(self) -> str:
        for s in self.steps:
            if s.reasons:
                return f"step {s.index} ({s.transition}): {s.reasons[0]}"
        return "" if self.completed else f"the played supervisor ended {self.supervisor}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "reason": self.reason,
            "backend": self.backend,
            "wall_s": self.wall_s,
            "controller_s": self.controller_s,
            "supervisor": self.supervisor,
            "completed": self.completed,
            "speeds": list(self.speeds),
            "steps": [s.to_dict() for s in self.steps],
        }


# ---- 1. singularities along each step --------------------------------------------------------


def step_conditioning(
    model: pin.Model,
    spec: ControllerSpec,
    traj: StepTrajectory,
    sample_period_s: float = 0.05,
) -> tuple[float, str]:
    """The smallest singular value any level of ``spec`` needs along ``traj`` (its streamed
    posture reference, else its configurations, every ``sample_period_s`` and at both ends),
    and where: "<tasks> at t = <s> s"."""
    data = model.createData()
    q = traj.references["posture"][0] if "posture" in traj.references else traj.q
    every = max(1, round(sample_period_s / traj.dt))
    worst, where = float("inf"), ""
    for k in sorted({*range(0, len(q), every), len(q) - 1}):
        for level in level_conditioning(model, data, spec, q[k]):
            if level.sigma_min < worst:
                worst = level.sigma_min
                where = f"{', '.join(level.tasks)} at t = {traj.t[k]:.2f} s"
    return worst, where


def singular_crossings(
    model: pin.Model,
    steps: list[Step],
    specs: list[ControllerSpec],
    trajectories: dict[int, StepTrajectory],
    options: DryRunOptions,
    verdicts: dict[int, StepVerdict],
) -> None:
    """Fills each verdict's conditioning; a level below ``options.singular_threshold`` is a
    reason."""
    for step, spec in zip(steps, specs):
        if step.index not in trajectories:
            continue
        v = verdicts[step.index]
        v.min_singular_value, v.singular_level = step_conditioning(
            model, spec, trajectories[step.index], options.sample_period_s
        )
        if v.min_singular_value < options.singular_threshold:
            v.reasons.append(
                f"crosses a singularity: {v.singular_level} the level keeps a singular value "
                f"of {v.min_singular_value:.3g} < {options.singular_threshold:g} (damped, its "
                "task is no longer tracked)"
            )


# ---- 2. played on the kinematic backend ------------------------------------------------------


class _StateLog:
    """(utime, q) of the ROBOT_STATE messages (every one: the kinematic backend publishes at
    100 Hz of wall time)."""

    def __init__(self, client: ControllerClient, model: pin.Model) -> None:
        self.model = model
        self.rows: list[tuple[int, np.ndarray]] = []
        self._lock = threading.Lock()
        client.bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)

    def _on_state(self, msg: Any) -> None:
        with self._lock:
            self.rows.append((int(msg.utime), configuration_from_state(self.model, msg)))

    def between(self, t0: int, t1: int) -> list[tuple[int, np.ndarray]]:
        with self._lock:
            return [(u, q) for u, q in self.rows if t0 <= u <= t1]


def _posture_joints(model: pin.Model, spec: ControllerSpec) -> list[tuple[str, int]]:
    """(name, idx_q) of the 1-DoF joints the step's posture follows."""
    posture = next((t for t in spec.tasks if t.kind == "posture"), None)
    names = (
        list(posture.joints)
        if posture is not None and posture.joints
        else [model.names[j] for j in range(1, model.njoints) if model.joints[j].nv == 1]
    )
    return [(n, model.joints[model.getJointId(n)].idx_q) for n in names]


def joint_deviation(
    model: pin.Model,
    spec: ControllerSpec,
    traj: StepTrajectory,
    start_utime: int,
    states: list[tuple[int, np.ndarray]],
) -> tuple[float, str]:
    """The largest |q_j − q_ref,j| over ``states`` (utime, q) of the step's posture joints,
    q_ref the streamed posture reference at the same controller time (its last sample after
    the end), and the joint and time where it is reached."""
    ref = traj.references["posture"][0] if "posture" in traj.references else traj.q
    joints = _posture_joints(model, spec)
    idx = np.array([i for _, i in joints], dtype=int)
    dt_us = round(traj.dt * 1e6)
    worst, where = 0.0, ""
    for utime, q in states:
        k = int(np.clip((utime - start_utime) // dt_us, 0, len(ref) - 1))
        d = np.abs(q[idx] - ref[k, idx])
        j = int(np.argmax(d))
        if d[j] > worst:
            worst, where = (
                float(d[j]),
                f"{joints[j][0]} at t = {(utime - start_utime) * 1e-6:.2f} s",
            )
    return worst, where


def _go_to(client: ControllerClient, model: pin.Model, q_goal: np.ndarray, limits: np.ndarray):
    """Brings the kinematic robot to ``q_goal`` (a posture move at rest at both ends, within
    ``limits``): the plan may start elsewhere than the controller's reference posture."""
    q_now = configuration_from_state(model, client.state)
    dq = pin.difference(model, q_now, q_goal)
    if np.abs(dq).max() < 1e-4:
        return
    T = max(0.5, 15.0 / 8.0 * float(np.max(np.abs(dq) / limits)))
    s, sdot = minimum_jerk(np.zeros(1), np.ones(1), T, 1e-3)
    values = np.array([pin.integrate(model, q_now, u * dq) for u in s[:, 0]])
    derivatives = sdot * dq[None, :]
    cid = int(time.time() * 10) % 1_000_000_000 + 7
    spec = ControllerSpec(
        cid,
        "dry run: to the plan's start",
        [TaskSpec("posture", "posture", 0, gain=2.0, streamed=True)],
        max_switch_velocity_jump=0.1,
        reference_timeout=0.5,
    )
    client.send_spec(spec)
    client.wait(lambda c: c.status.active_controller_id == cid, 20.0, "the start move's controller")
    from marionette.execution.streamer import stream_to_end

    streamer = stream_to_end(client, cid, {"posture": (values, derivatives)})
    client.wait_past(streamer.end_utime + 1_000_000, 60.0, "the start move to end")


def play(
    robot: str,
    steps: list[Step],
    specs: list[ControllerSpec],
    robot_map: PlanRobotMap,
    trajectories: dict[int, StepTrajectory],
    supervisor_options: Any,
    verdicts: dict[int, StepVerdict],
    options: DryRunOptions,
    log_dir: Path | None = None,
    q_start: np.ndarray | None = None,
) -> tuple[bool, str, float]:
    """Plays ``steps`` on a kinematic marionette-controller started here (module doc, part 2)
    and fills the verdicts; returns whether the supervisor reached done, its end (state and
    reason) and the controller time played [s]. ``q_start`` (nq): where the robot starts
    (default: the first step's start)."""
    from marionette.execution.supervisor import Supervisor
    from marionette.lcm_bus import private_lcm_url
    from marionette.processes import SHARED_MACHINE_SUPERVISOR_TIMEOUT_S, ProcessGroup

    model = robot_map.model
    url = private_lcm_url()
    with tempfile.TemporaryDirectory(prefix="dry-run-") as tmp:
        logs = log_dir or Path(tmp)
        with ProcessGroup(url, logs) as group, ControllerClient(url) as client:
            group.start(
                "dry-run-controller",
                [
                    str(marionette.BUILD_DIR / "marionette-controller"),
                    "--lcm-url",
                    url,
                    "--robot",
                    controller_robot_argument(robot),
                    "--backend",
                    "kinematic",
                    "--speed",
                    str(options.speed),
                    "--camera-rate",
                    "0",
                    "--status-rate",
                    "100",
                    "--supervisor-timeout",
                    str(SHARED_MACHINE_SUPERVISOR_TIMEOUT_S),
                ],
            )
            client.wait_ready(options.ready_timeout_s, processes=group)
            limits = velocity_limits(model, supervisor_options.max_joint_velocity)
            start = robot_map.robot_q(steps[0].q[0]) if q_start is None else q_start
            _go_to(client, model, start, limits)
            states = _StateLog(client, model)
            opts = dataclasses.replace(supervisor_options, simulated_grasps=False, step_mode=False)
            supervisor = Supervisor(client, steps, specs, robot_map, opts, "dry-run")
            supervisor.trajectories = dict(trajectories)
            utime0 = client.utime()
            result = supervisor.run(steps[0].index)
            played_s = (client.utime() - utime0) * 1e-6
            group.check_alive()
    for r in result.records:
        v = verdicts[r.index]
        v.played = True
        v.controller_s = (r.utime_end - r.utime_start) * 1e-6 if r.utime_end else 0.0
        v.switch = (
            "accepted" + (f" after {r.switch_retries} retries" if r.switch_retries else "")
            if r.utime_start
            else ""
        )
        v.converged = bool(r.utime_end)
        if r.utime_reference_start:
            traj = trajectories[r.index]
            end = r.utime_end or r.utime_reference_end + int(
                supervisor_options.converge_timeout_s * 1e6
            )
            v.max_joint_deviation, v.deviation_joint = joint_deviation(
                model,
                specs[r.index],
                traj,
                r.utime_reference_start,
                states.between(r.utime_reference_start, end),
            )
            if v.max_joint_deviation > options.branch_tolerance:
                v.reasons.append(
                    f"leaves the planned IK branch: {v.deviation_joint} "
                    f"{v.max_joint_deviation:.2f} rad from its reference "
                    f"(> {options.branch_tolerance:g})"
                )
        if r.result and r.result != "ok":
            event = r.result.split(":", 1)[0]
            if event in ("switch_refused", "spec_rejected"):
                v.switch = r.result
                v.reasons.append(f"its switch would be refused: {r.result}")
            elif event == "end_check_failed":
                v.reasons.append(f"a task would not converge: {r.result}")
            else:
                v.reasons.append(f"played: {r.result}")
    final = f"{result.state}" + (f" ({result.reason})" if result.reason else "")
    return result.success, final, played_s


def dry_run(
    robot: str,
    steps: list[Step],
    specs: list[ControllerSpec],
    robot_map: PlanRobotMap,
    trajectories: dict[int, StepTrajectory],
    supervisor_options: Any,
    options: DryRunOptions | None = None,
    log_dir: Path | None = None,
    q_start: np.ndarray | None = None,
    gripper_frames: dict[str, str] | None = None,
) -> DryRun:
    """Both parts of the module doc on ``steps`` (their controllers ``specs`` and the
    ``trajectories`` the supervisor streams): the verdict per step; with ``gripper_frames``
    (gripper -> its frame in the robot model) each step's static load too."""
    options = options or DryRunOptions()
    t0 = time.perf_counter()
    loads = {}  # of the plan, whatever pace it is played at: computed once
    if gripper_frames is not None:
        contacts = [c.link for c in robots.semantics(robot).contacts]
        for step in steps:
            load = step_static_load(robot_map.model, robot_map, step, gripper_frames, contacts)
            if load is not None:
                loads[step.index] = load
    speeds: list[float] = []
    for speed in (options.speed, options.fallback_speed):
        speeds.append(speed)
        verdicts = {s.index: StepVerdict(s.index, s.transition) for s in steps}
        singular_crossings(robot_map.model, steps, specs, trajectories, options, verdicts)
        for index, load in loads.items():
            verdicts[index].static_load = load.ratio
            verdicts[index].static_load_joint = load.joint
        completed, supervisor, played_s = play(
            robot,
            steps,
            specs,
            robot_map,
            trajectories,
            supervisor_options,
            verdicts,
            dataclasses.replace(options, speed=speed),
            log_dir,
            q_start,
        )
        if "reference_starved" not in supervisor:
            break
    return DryRun(
        "kinematic",
        [verdicts[s.index] for s in steps],
        time.perf_counter() - t0,
        played_s,
        supervisor,
        completed,
        tuple(speeds),
    )
