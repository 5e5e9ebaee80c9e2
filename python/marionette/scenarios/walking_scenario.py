"""What the walking scenarios (``grasp-walk``, Dang 2012 ch. 6; ``step-over``, ch. 5) share: a
humanoid on marionette-controller's walking stack, the footstep process planning towards an
object its head camera measures (OBJECT_POSES), and that object slid by the simulator during the
walk so that the footstep process replans (the ball's pedestal, the bar).

* :class:`SlidingFixture` — a fixture of the scene the simulator carries to a new pose at
  constant speed (an object the robot has to see: its camera and perception measure it);
* :class:`WalkRecorder` — WALK_STATUS, ROBOT_STATE and FOOTSTEP_PLAN as the verdicts and plots
  need them (plans merged as the footstep manager applies them);
* :func:`watching_walk` — the processes and walking stack of a walk whose head camera watches the
  moved object;
* :func:`walking_run` — the trial's processes (:mod:`.harness`), the walking stack, the standing
  stance and the timings;
* :func:`walk_while_object_moves` — footstep process start, first plan, the move at a given step,
  the wait for the robot standing at the end of the last plan;
* measures and report pieces both verdicts use (:func:`sole_poses`, :func:`landings`,
  :func:`step_counts`, :func:`replan_criteria`, :func:`plot_footsteps`,
  :func:`finish_footsteps_axes`).

The scenario modules keep what differs: the object, the footstep process's arguments, the
criteria, the report text and the plots beyond the footsteps.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import (
    channels,
    lcmt_footstep_plan,
    lcmt_object_poses,
    lcmt_robot_state,
    lcmt_walk_status,
)
from marionette.control.client import ControllerClient, configuration_from_state
from marionette.control.spec import ControllerSpec, reference_chunk
from marionette.execution.walking import FEET, MergedPlan, loaded_soles, walking_spec
from marionette.scenarios.base import RunOptions
from marionette.scenarios.harness import Processes, Run, harness

MIN_REPLAN_HZ = 20.0  # footstep replanning at 20 Hz or more (median replan < 50 ms)
SETTLE_S = 1.5  # [s] of controller time standing before a walk counts as done
# [deg] a watched object rests upright: an estimate tilting it more is wrong (perceive
# --max-tilt-deg; the pedestal's correct estimates tilt less than 1 deg over 500, and no bar
# estimate of a step-over trial was dropped)
MAX_TILT_DEG = 5.0


class SlidingFixture:
    """A fixture of the scene (a MuJoCo mocap body: the step-over's bar, the ball's pedestal) that
    the simulator carries while the robot walks (SIM_COMMAND ``slide``, constant speed): the
    robot's camera sees it move and its feet meet it where it is (the moved object of
    :func:`walk_while_object_moves`). The scenario speaks in floor poses (x, y, yaw):
    ``body_pose(pose)`` is the body's world pose for the simulator and ``floor_pose(X)`` the way
    back; ``history`` keeps (controller utime, floor pose) of every OBJECT_POSES estimate of the
    body (what the robot perceived), for the verdict and the plots; ``on_estimate(X)`` is called
    with each (a :class:`GazeFollower` turning the head to it)."""

    def __init__(
        self,
        client: ControllerClient,
        name: str,
        body_pose: Callable[[np.ndarray], pin.SE3],
        floor_pose: Callable[[pin.SE3], np.ndarray],
        on_estimate: Callable[[pin.SE3], None] | None = None,
    ) -> None:
        self.client, self.name, self.stop = client, name, threading.Event()
        self.body_pose, self.floor_pose, self.on_estimate = body_pose, floor_pose, on_estimate
        self.history: list[tuple[int, np.ndarray]] = []
        self.last: pin.SE3 | None = None  # the latest estimate's pose
        self.last_utime = -1  # its message's controller utime
        self._lock = threading.Lock()

    def start(self) -> None:
        self.client.bus.subscribe(channels.OBJECT_POSES, lcmt_object_poses, self._on_poses)

    def _on_poses(self, msg) -> None:
        if self.stop.is_set():
            return
        for o in msg.objects:
            if o.object_name == self.name:
                X = pin.XYZQUATToSE3(
                    [*o.position_world, *o.quaternion_world[1:], o.quaternion_world[0]]
                )
                with self._lock:
                    self.history.append((int(msg.utime), self.floor_pose(X)))
                    self.last, self.last_utime = X, int(msg.utime)
                if self.on_estimate is not None:
                    self.on_estimate(X)

    def move(self, pose: np.ndarray, duration_s: float) -> int:
        """Starts the slide to ``pose`` now; returns its controller utime."""
        utime = self.client.utime()
        self.client.slide_object(self.name, self.body_pose(pose), duration_s)
        return utime

    def perceived(self) -> list[tuple[int, np.ndarray]]:
        with self._lock:
            return list(self.history)

    def at_rest(
        self, count: int = 2, tolerance: float = 0.01, since_utime: int = -1
    ) -> pin.SE3 | None:
        """The latest estimate if the object was seen at rest: the last ``count`` estimates, all
        at or after controller ``since_utime``, within ``tolerance`` [m] of it on the floor; else
        None (too few, or the object was still moving when last seen)."""
        with self._lock:
            recent = self.history[-count:]
            if len(recent) < count or recent[0][0] < since_utime:
                return None
            last = recent[-1][1][:2]
            if any(np.linalg.norm(pose[:2] - last) > tolerance for _, pose in recent):
                return None
            return self.last


class GazeFollower:
    """Keeps the head camera on a tracked object while the robot walks (Dang 2012 ch. 6: the
    ball followed by the robot's cameras): streams the target of the walking stack's ``gaze`` task
    (:func:`walking.walking_spec` with ``gaze``), the point ``point_O`` of the object at each new
    estimate of its pose, over a ``ramp_s`` linear ramp from the last target (the head turns
    smoothly, not by steps), each chunk the stream's last (it holds its end). The first target is
    the point with the object at ``X_WO``, where the walking stack's gaze starts."""

    def __init__(
        self,
        client: ControllerClient,
        controller_id: int,
        point_O: np.ndarray,
        X_WO: pin.SE3,
        ramp_s: float = 0.2,
    ) -> None:
        self.client, self.controller_id = client, controller_id
        self.point_O = np.asarray(point_O, dtype=float)
        self.target = X_WO.act(self.point_O)
        self.ramp_samples = max(1, round(ramp_s * 1e3))
        self.sequence = 0
        self._lock = threading.Lock()

    def follow(self, X_WO: pin.SE3) -> None:
        """A new estimate of the object's pose: the gaze moves to its point."""
        self.look_at(X_WO.act(self.point_O))

    def look_at(self, target: np.ndarray) -> None:
        """The gaze moves to the world point ``target``."""
        target = np.asarray(target, dtype=float)
        with self._lock:
            s = np.linspace(0.0, 1.0, self.ramp_samples)[:, None]
            values = self.target + s * (target - self.target)
            rate = (target - self.target) / (max(self.ramp_samples - 1, 1) * 1e-3)
            derivatives = np.repeat(rate[None, :], self.ramp_samples, axis=0)
            derivatives[-1] = 0.0
            start = (self.client.utime() // 1000 + 1) * 1000  # on the stream's 1 ms grid
            self.client.send_reference(
                reference_chunk(
                    self.controller_id,
                    "gaze",
                    start,
                    values,
                    derivatives,
                    last=True,
                    sequence=self.sequence,
                )
            )
            self.sequence += 1
            self.target = target


def search_points(
    around_W: np.ndarray, radii: tuple[float, ...] = (0.15, 0.3), directions: int = 8
) -> list[np.ndarray]:
    """Where the head looks for an object lost from view: ``around_W`` (its last known point),
    then rings of ``radii`` [m] around it in the horizontal plane, ``directions`` points each."""
    points = [np.asarray(around_W, dtype=float)]
    for radius in radii:
        for k in range(directions):
            a = 2.0 * np.pi * k / directions
            points.append(points[0] + radius * np.array([np.cos(a), np.sin(a), 0.0]))
    return points


def look_for(
    client: ControllerClient,
    fixture: SlidingFixture,
    gaze: GazeFollower,
    points_W: list[np.ndarray],
    dwell_s: float = 1.5,
) -> tuple[pin.SE3 | None, int]:
    """``fixture`` seen at rest (:meth:`SlidingFixture.at_rest`), the estimate a robot can act on:
    one taken while the object moved shows it where it no longer is. If the last estimates do not
    show it at rest, the head looks at each of ``points_W`` in turn (the first: where it was last
    seen) for ``dwell_s`` of controller time until estimates made from then on do; an estimate
    turns the gaze to the object itself (``fixture.on_estimate``). Returns (the estimate or None,
    the head directions looked in: 0 if the last estimates sufficed). The fixture must be
    receiving (``fixture.stop`` clear)."""
    if (X := fixture.at_rest()) is not None:
        return X, 0
    for i, point in enumerate(points_W):
        gaze.look_at(point)
        start = client.utime()
        while client.utime() < start + round(dwell_s * 1e6):
            client.wait_time(0.05)
            if (X := fixture.at_rest(since_utime=start)) is not None:
                return X, i + 1
    return None, len(points_W)


class WalkRecorder:
    """Everything the judgement and the plots need, filled by LCM handlers (background thread):
    every WALK_STATUS, the loaded soles of every ROBOT_STATE, configurations at 50 Hz, each
    FOOTSTEP_PLAN with the controller utime at its reception, and the plans merged."""

    def __init__(self, client: ControllerClient, model: pin.Model) -> None:
        self.model = model
        self.statuses: list[Any] = []
        self.loaded: dict[int, list[str]] = {}
        self.utimes: list[int] = []
        self.q: list[np.ndarray] = []
        self.plans: list[tuple[int, Any]] = []  # (controller utime at reception, plan)
        self.merged = MergedPlan()
        self._lock = threading.Lock()
        client.bus.subscribe(channels.WALK_STATUS, lcmt_walk_status, self._on_status)
        client.bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)
        client.bus.subscribe(channels.FOOTSTEP_PLAN, lcmt_footstep_plan, self._on_plan)
        self._last_utime = 0

    def _on_status(self, msg) -> None:
        with self._lock:
            self.statuses.append(msg)

    def _on_state(self, msg) -> None:
        with self._lock:
            self._last_utime = msg.utime
            self.loaded[msg.utime] = loaded_soles(msg)
            if len(self.q) == 0 or msg.utime - self.utimes[-1] >= 20000:  # 50 Hz for plots
                self.utimes.append(msg.utime)
                self.q.append(configuration_from_state(self.model, msg))

    def _on_plan(self, msg) -> None:
        with self._lock:
            self.plans.append((self._last_utime, msg))
            current = self.statuses[-1].current_step_index if self.statuses else -1
            self.merged.apply(msg, current)

    def last_status(self):
        """The latest WALK_STATUS, None before the first."""
        with self._lock:
            return self.statuses[-1] if self.statuses else None


def walk_done(rec: WalkRecorder, settle_s: float) -> bool:
    """Standing on the latest plan, at least one step walked, for ``settle_s`` of controller time
    with no plan since (a walk starts 1.6 s after its plan arrives, so a later plan would show)."""
    with rec._lock:
        if not rec.plans or not rec.statuses:
            return False
        last_plan_utime = rec.plans[-1][0]
        latest = rec.statuses[-1]
        walked = any(s.current_step_index >= 0 for s in rec.statuses)
        since = [s for s in rec.statuses if s.utime >= latest.utime - settle_s * 1e6]
    return (
        walked
        and latest.utime - last_plan_utime > 2.0e6
        and latest.utime - since[0].utime >= 0.9 * settle_s * 1e6
        and all(s.phase == "standing" for s in since)
    )


def sole_poses(model: pin.Model, q: np.ndarray) -> dict[str, np.ndarray]:
    """Sole (x, y, z, yaw) of each foot at configuration ``q`` (``<side>_sole_link`` frames)."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    out = {}
    for side in FEET:
        X = data.oMf[model.getFrameId(f"{side}_sole_link")]
        out[side] = np.array([*X.translation, np.arctan2(X.rotation[1, 0], X.rotation[0, 0])])
    return out


def landings(rec: WalkRecorder, model: pin.Model) -> list[tuple[str, np.ndarray]]:
    """Measured sole (x, y, z, yaw) of each swing foot 0.1 s after its swing phase ends."""
    out = []
    utimes = np.array(rec.utimes)
    for a, b in zip(rec.statuses, rec.statuses[1:]):
        if a.phase.endswith("_swing") and a.phase != b.phase:
            side = a.phase.split("_")[0]
            k = int(np.searchsorted(utimes, b.utime + 100000))
            if k < len(rec.q):
                out.append((side, sole_poses(model, rec.q[k])[side]))
    return out


def replan_solve_ms(footsteps_log: list[str]) -> dict[str, float | None]:
    """Solve times of the footstep process from its log lines ``footsteps: plan ... (<t> ms)``:
    the first plan's, and the median and max of the replans (None without replans)."""
    solve_ms = [
        float(line.rsplit("(", 1)[1].split(" ms")[0])
        for line in footsteps_log
        if line.startswith("footsteps: plan ") and " ms)" in line
    ]
    return {
        "median": float(np.median(solve_ms[1:])) if len(solve_ms) > 1 else None,
        "max": float(np.max(solve_ms[1:])) if len(solve_ms) > 1 else None,
        "first_plan": solve_ms[0] if solve_ms else None,
    }


def replan_rates(
    rec: WalkRecorder,
    solve_ms: dict[str, float | None],
    utime_move: int | None,
    move_duration_s: float,
) -> dict[str, float | None]:
    """Footstep replanning rates (the target: replanning at 20 Hz or more): ``capacity_hz``,
    1 / the median replan time (the rate the process sustains, whatever the input rate);
    ``slowest_hz``, 1 / the slowest replan (step-over's fallback to a fresh sequence when the bar
    moves beyond the strides' reach takes up to ~0.5 s); ``during_move_hz``, the plans received
    while the object moved per second of controller time (the process replans on every pose
    update, 20 Hz of wall time: at ``--speed 0`` controller time runs faster than the wall clock
    and the figure is lower)."""
    during = None
    if utime_move is not None and move_duration_s > 0:
        end = utime_move + move_duration_s * 1e6
        during = sum(utime_move <= u <= end for u, _ in rec.plans) / move_duration_s
    median, slowest = solve_ms.get("median"), solve_ms.get("max")
    return {
        "capacity_hz": None if not median else 1e3 / median,
        "slowest_hz": None if not slowest else 1e3 / slowest,
        "during_move_hz": during,
    }


def replan_criteria(
    rec: WalkRecorder, footsteps_log: list[str], utime_move: int | None, move_duration_s: float
) -> dict[str, Any]:
    """The replanning entries of a walking demo's criteria: solve times
    (:func:`replan_solve_ms`), rates (:func:`replan_rates`) and ``replan_fast_enough`` (1 / the
    median replan at least :data:`MIN_REPLAN_HZ`)."""
    solve_ms = replan_solve_ms(footsteps_log)
    rates = replan_rates(rec, solve_ms, utime_move, move_duration_s)
    return {
        "replan_solve_ms": solve_ms,
        "replan_rate_hz": rates,
        "replan_fast_enough": bool(
            rates["capacity_hz"] is not None and rates["capacity_hz"] >= MIN_REPLAN_HZ
        ),
    }


def replan_rate_row(c: dict[str, Any], moved: str) -> str:
    """The report.md criteria row of :func:`replan_rates`."""
    r = c["replan_rate_hz"]

    def hz(v):
        return "-" if v is None else f"{v:.0f} Hz"

    return (
        f"| footstep replanning: 1 / median replan (1 / slowest; plans per controller second "
        f"while the {moved} moved) | {hz(r['capacity_hz'])} ({hz(r['slowest_hz'])}; "
        f"{hz(r['during_move_hz'])}) | >= {MIN_REPLAN_HZ:.0f} Hz | {c['replan_fast_enough']} |"
    )


def step_counts(rec: WalkRecorder, statuses: list[Any]) -> dict[str, Any]:
    """The steps of a walk: planned by the first plan, executed (the highest step index the
    ``statuses`` show, + 1), executed in order (indices never go back), and the plans received."""
    indices = [s.current_step_index for s in statuses if s.current_step_index >= 0]
    return {
        "steps_planned_first": int(rec.plans[0][1].num_steps),
        "steps_executed": int(max(indices) + 1) if indices else 0,
        "steps_in_order": bool(indices == sorted(indices)),
        "footstep_plans": len(rec.plans),
    }


def draw_floor_move(seed: int, max_distance: float = 0.3, min_distance: float = 0.1) -> np.ndarray:
    """A seeded move of an object on the floor (moved by up to 0.3 m while the robot walks):
    direction uniform, distance uniform in [``min_distance``, ``max_distance``] [m];
    returns (dx, dy). Every trial moves the object by a distance that matters to the planner."""
    if not 0.0 <= min_distance <= max_distance:
        raise ValueError(
            f"need 0 <= min_distance <= max_distance, got {min_distance}, {max_distance}"
        )
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0.0, 2.0 * np.pi)
    distance = rng.uniform(min_distance, max_distance)
    return distance * np.array([np.cos(angle), np.sin(angle)])


class WalkingRun:
    """One walking trial's live run (:func:`walking_run`): the harness's :class:`~.harness.Run`
    (processes, controller client), the recorder, the stance the robot stands in before it walks
    and the report's timings."""

    def __init__(
        self, run: Run, rec: WalkRecorder, model: pin.Model, timings: dict[str, float]
    ) -> None:
        self.run, self.rec, self.model, self.timings = run, rec, model, timings
        self.client, self.group, self.url = run.client, run.group, run.url
        standing = rec.last_status()
        self.start = {side: np.array(getattr(standing, f"{side}_foot")) for side in FEET}
        self.mid = 0.5 * (self.start["left"][:2] + self.start["right"][:2])  # stance centre (x, y)
        self.q_start = rec.q[-1].copy()
        self.utime_start = self.client.utime()
        self.q_final: np.ndarray | None = None  # set by walk_while_object_moves
        self.footsteps_log: list[str] = []  # the footstep process's log, at the end


def watching_walk(
    robot: str,
    scene_text: str,
    source: Path,
    out_dir: Path,
    tracked: str,
    camera_rate: float,
    position_sigma: float,
    head_pitch: float | None = None,
    gaze: np.ndarray | None = None,
) -> tuple[Processes, ControllerSpec]:
    """A walk that watches ``tracked`` (an object of ``models/objects``, resting z up) with the
    head camera: the processes — the trial's scene (MJCF ``scene_text`` of ``source`` written to
    ``out_dir/scene.xml``), the head camera rendered at ``camera_rate`` [Hz of controller time],
    ``marionette perceive`` publishing ``tracked`` when its position is known to
    ``position_sigma`` [m] — and the walking stack (for :func:`walking_run`). The head either
    holds ``head_pitch`` (and yaw 0) or keeps the world point ``gaze`` at the image centre
    (moved by a :class:`GazeFollower`); the scene starts it there (:func:`aim_head`)."""
    import marionette
    from marionette import robots
    from marionette.scenarios.perturbations import set_keyframe_joints, write_scene

    if gaze is not None:
        head = aim_head(robot, np.asarray(gaze, dtype=float))
        x, y, z = (float(v) for v in gaze)
        spec = walking_spec(robot, 1, gaze=(x, y, z))
    elif head_pitch is not None:
        head = dict(zip(robots.robot(robot).calibration_head_joints, (head_pitch, 0.0)))
        spec = walking_spec(robot, 1, head_pitch=head_pitch)
    else:
        raise ValueError("watching_walk: give head_pitch or gaze")
    scene = write_scene(set_keyframe_joints(scene_text, head), source, out_dir / "scene.xml")
    processes = Processes(
        robot,
        scene,
        camera_rate=camera_rate,
        perceive=(
            "--robot",
            robot,
            "--objects",
            str(marionette.MODELS_DIR / "objects" / f"{tracked}.yaml"),
            "--up-axis",
            f"{tracked}:0,0,1",
            "--max-position-sigma",
            str(position_sigma),
            "--max-tilt-deg",
            str(MAX_TILT_DEG),
        ),
    )
    return processes, spec


def aim_head(robot: str, target_W: np.ndarray) -> dict[str, float]:
    """The head's (pitch, yaw) joints (robot.yaml calibration ``head_joints``) that bring the
    world point ``target_W`` to the centre of the head camera's image, the robot in its reference
    configuration; within the joints' limits (the nearest reachable when it is not)."""
    from scipy.optimize import least_squares

    from marionette import robots

    desc = robots.robot(robot)
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    data = model.createData()
    q = robots.reference_configuration(robot, model)
    idx = [model.joints[model.getJointId(j)].idx_q for j in desc.calibration_head_joints]
    camera = model.getFrameId(desc.camera_frame)

    def image(x: np.ndarray) -> np.ndarray:
        q[idx] = x
        pin.framesForwardKinematics(model, data, q)
        p = data.oMf[camera].actInv(target_W)
        return p[:2] / max(p[2], 1e-3)  # normalised image coordinates, (0, 0) at the centre

    lower, upper = model.lowerPositionLimit[idx], model.upperPositionLimit[idx]
    x = least_squares(image, np.clip(q[idx], lower, upper), bounds=(lower, upper)).x
    return {j: float(v) for j, v in zip(desc.calibration_head_joints, x)}


@contextlib.contextmanager
def walking_run(
    robot: str,
    model: pin.Model,
    scene: Path,
    out_dir: Path,
    options: RunOptions,
    report: dict[str, Any],
    processes: Processes | None = None,
    spec: ControllerSpec | None = None,
) -> Iterator[WalkingRun]:
    """Starts the trial's processes on ``scene`` (:func:`.harness.harness`; ``processes`` when
    the trial needs more: a camera, perception), sends the walking stack (``spec``, default
    :func:`walking.walking_spec`, id 1) and yields once it runs and WALK_STATUS says
    standing. Afterwards ``report["timings"]`` has ``total_wall_s`` and
    :attr:`WalkingRun.footsteps_log` is read from ``logs/footsteps.log``."""
    timings: dict[str, float] = {}
    report["timings"] = timings
    t0 = time.perf_counter()
    with harness(out_dir, processes or Processes(robot, scene), options, report) as run:
        client = run.client
        rec = WalkRecorder(client, model)
        client.send_spec(spec or walking_spec(robot, 1))
        run.wait(
            lambda c: c.status.mode == "running" and c.status.active_controller_id == 1,
            30.0,
            "the walking controller",
        )
        run.wait(
            lambda c: rec.last_status() is not None and rec.last_status().phase == "standing",
            10.0,
            "WALK_STATUS standing",
        )
        walking = WalkingRun(run, rec, model, timings)
        yield walking
    timings["total_wall_s"] = time.perf_counter() - t0
    walking.footsteps_log = (out_dir / "logs" / "footsteps.log").read_text().splitlines()


def walk_while_object_moves(
    run: WalkingRun,
    moved: SlidingFixture,
    footsteps_args: list[str],
    move_to: np.ndarray,
    move_at_step: int,
    move_duration_s: float,
    walk_timeout_s: float,
    started: str,
    tag: str,
    log: Callable[[str], None] = print,
) -> int:
    """The walk: starts keeping ``moved``'s estimates and the footstep process (``marionette
    footsteps run --lcm-url <url> <footsteps_args>``), logs ``started``, waits for the first
    plan, slides the object to ``move_to`` in ``move_duration_s`` when step ``move_at_step``
    starts, and waits for the robot standing at the end of the last plan (:func:`walk_done`);
    the estimates stop being kept in any case. Fills ``first_plan_wall_s``,
    ``walk_controller_s`` and :attr:`WalkingRun.q_final`; returns the controller utime of the
    move. Log lines start with ``tag``."""
    client, rec = run.client, run.rec
    moved.start()
    run.run.start_cli("footsteps", ["footsteps", "run", "--lcm-url", run.url, *footsteps_args])
    log(started)
    t1 = time.perf_counter()
    try:
        run.run.wait(lambda c: len(rec.plans) > 0, 120.0, "the first footstep plan")
        run.timings["first_plan_wall_s"] = time.perf_counter() - t1
        log(f"{tag}: plan 1, {rec.plans[0][1].num_steps} steps")
        run.run.wait(
            lambda c: rec.last_status().current_step_index >= move_at_step,
            walk_timeout_s * 2,
            f"step {move_at_step}",
        )
        utime_move = moved.move(move_to, move_duration_s)
        log(
            f"{tag}: {moved.name} moving to {np.round(move_to, 3).tolist()} from step "
            f"{rec.last_status().current_step_index} on, in {move_duration_s} s"
        )
        run.run.wait(
            lambda c: walk_done(rec, SETTLE_S),
            walk_timeout_s * 2,
            "the robot standing at the end of the last plan",
        )
    finally:
        moved.stop.set()
    run.timings["walk_controller_s"] = (client.utime() - run.utime_start) * 1e-6
    run.q_final = configuration_from_state(run.model, client.state)
    return utime_move


def plot_footsteps(ax, rec: WalkRecorder, model: pin.Model, foot) -> None:
    """Top view of the steps: the first plan dotted (faded), the executed plan (plans merged,
    numbered) and the measured soles at each landing dashed. ``foot``: FootShape of the soles."""
    from marionette.footsteps.plot import LEFT_COLOR, RIGHT_COLOR, _sole_outline

    first = MergedPlan()
    first.apply(rec.plans[0][1], -1)
    for _, is_left, pose in first.rows():
        o = _sole_outline(pose, foot)
        ax.plot(
            o[:, 0], o[:, 1], ":", color=LEFT_COLOR if is_left else RIGHT_COLOR, lw=1, alpha=0.6
        )
    for i, is_left, pose in rec.merged.rows():
        o = _sole_outline(pose, foot)
        ax.plot(o[:, 0], o[:, 1], color=LEFT_COLOR if is_left else RIGHT_COLOR, lw=1.3)
        ax.annotate(str(i), pose[:2], ha="center", va="center", fontsize=7)
    for k, (_, pose) in enumerate(landings(rec, model)):
        o = _sole_outline(pose, foot)
        ax.plot(
            o[:, 0], o[:, 1], "k--", lw=0.8, label="measured soles at landing" if k == 0 else None
        )


def finish_footsteps_axes(ax) -> None:
    """The legend entries of :func:`plot_footsteps`' plans (after the scenario's own entries),
    equal axes, grid, axis labels and the legend outside the axes."""
    ax.plot([], [], ":", color="0.3", label="first plan")
    ax.plot([], [], "-", color="0.3", label="executed plan (after replans)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
