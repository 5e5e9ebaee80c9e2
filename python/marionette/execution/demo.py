"""`marionette demo <scenario>`: plan (or load the cached plan), generate the controllers, start
marionette-controller (MuJoCo) and an LCM logger on one private LCM URL, estimate the initial
state, run the supervisor FSM, judge the run against the success criteria of ARCHITECTURE.md
§Demos, and write a report folder (report.md, report.json, plots, controllers.yaml, run.lcmlog).

Scenarios: ``plank-flip`` (TALOS turns the plank upside down, thesis 000 §3.4) and ``ur10-box``
(UR10 moves the box across the table, issue 7's end-to-end check). ur10-box runs open loop from
the planned references (the thesis's chapter-3 setting); plank-flip closes the loop on vision
(§5.3.1): the controller renders the head camera, ``marionette perceive`` publishes the plank's
pose, the head looks at the plank and the carry to the placement is servoed on the measured pose
(:mod:`.visual_servo`). Before the controller starts, the head camera calibrates the encoder
offsets of both arms from their wrist tags (thesis 000 ch. 4.2, :mod:`..perception.arm_calibration`)
and the controller runs with them (``--encoder-offsets``). ``perturbation`` (:mod:`.perturbations`,
``--perturb issue10``) adds the seeded perturbations of issue #10; without it the objects start
where the problem file says.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

import marionette
from marionette import channels, lcmt_robot_state, robots
from marionette.control.client import ControllerClient, configuration_from_state
from marionette.execution.estimation import (
    estimate_state,
    first_step_to_run,
    measured_configuration,
)
from marionette.execution.factory import (
    ADMITTANCE,
    build_specs,
    check_specs,
    context_from_plan,
    write_specs,
)
from marionette.execution.grip_force import (
    GripForceRecorder,
    holding_windows,
    recorder_for,
    settled_windows,
)
from marionette.execution.perturbations import (
    Perturbation,
    displaced,
    scene_with_joint_offsets,
    slipped,
)
from marionette.execution.plan_steps import PlanRobotMap, plan_robot, steps_from_plan
from marionette.execution.references import compute_references, dwell, sample_step
from marionette.execution.supervisor import Supervisor, SupervisorOptions, SupervisorResult
from marionette.lcm_bus import private_lcm_url
from marionette.perception.arm_calibration import calibrate_arm, encoder_offsets_argument
from marionette.planning.path import Plan, load_plan
from marionette.processes import ProcessGroup

PROBLEMS_DIR = Path(__file__).resolve().parents[1] / "planning" / "problems"


@dataclass(frozen=True)
class Scenario:
    """A demo: the problem to plan, the MuJoCo scene, execution settings and success limits."""

    name: str
    problem: str
    scene: Path
    seed: int
    object_name: str
    max_joint_velocity: float  # [rad/s] time law of the planned paths
    position_tolerance: float = 0.01  # [m]   object final pose vs the plan's goal
    angle_tolerance_deg: float = 5.0
    feet: tuple[str, ...] = ()  # frames that must never move (humanoid)
    feet_tolerance: float = 0.005  # [m]
    description: str = ""
    runner: Callable[..., dict[str, Any]] | None = None  # a demo with its own flow (no plan/FSM)
    vision: bool = False  # camera + perception + PBVS on the carried object (ch. 5)
    camera_rate: float = 5.0  # [Hz of controller time] head camera frames with vision
    servo_slowdown: float = 3.0  # servoed steps run this much slower: more frames to servo on
    quad_decimate: float = 2.0  # perceive's AprilTag decimation (1: small or oblique tags too)
    servo_dwell_s: float = 2.0  # a servoed step waits this long at its pre-grasp / pre-placement
    # gripper_admittance tasks on the grippers with a joint (issue 7: close on the handle, hold
    # 5 N, release), and the grip force measured on the jaws as a success criterion (± grip_tolerance).
    gripper_admittance: bool = False
    grip_tolerance: float = 1.0  # [N]
    # Arms whose encoder offsets the head camera calibrates before execution (thesis 000 ch. 4.2,
    # :mod:`marionette.perception.arm_calibration`); the controller then corrects its encoders.
    calibrate_arms: tuple[str, ...] = ()


def _grasp_walk(*args: Any, **kwargs: Any) -> dict[str, Any]:
    from marionette.execution.grasp_walk import run_grasp_walk

    return run_grasp_walk(*args, **kwargs)


SCENARIOS: dict[str, Scenario] = {
    "plank-flip": Scenario(
        "plank-flip",
        "talos_plank",
        marionette.MODELS_DIR / "scenes" / "talos_plank.xml",
        4,
        "plank",
        0.5,
        feet=("left_sole_link", "right_sole_link"),
        description="TALOS turns the plank upside down with both grippers (thesis 000 §3.4), "
        "the first grasp and the placement servoed on the plank pose seen by the head "
        "camera (§5.3.1)",
        # On the table the plank's tags face the head 60-70° off their normal: found at
        # decimation 1 only (1-2 mm / 0.2° along the approach, test_visual_servo.py).
        vision=True,
        quad_decimate=1.0,
        calibrate_arms=("left", "right"),
    ),
    "ur10-box": Scenario(
        "ur10-box",
        "ur10_box",
        marionette.MODELS_DIR / "scenes" / "ur10_box.xml",
        0,
        "box",
        1.0,
        description="UR10 picks the box with its two-finger gripper, holds it with 5 N (gripper "
        "admittance, thesis 000 §3.2.4.3) and places it 0.5 m away",
        gripper_admittance=True,
    ),
    "grasp-walk": Scenario(
        "grasp-walk",
        "",
        marionette.MODELS_DIR / "talos" / "talos.xml",
        0,
        "ball",
        0.0,
        description="TALOS walks to a ball moved sideways while it walks; the footstep process "
        "replans, the controller walks the new steps (thesis 001 ch. 6, no final grasp)",
        runner=_grasp_walk,
    ),
}
# `marionette demo` without a scenario (`make demo`): the one that meets its criteria reliably.
# The embedded default (issue #10): plank-flip, the thesis's experiment, with its arms calibrated by
# the head camera and vision in the loop (execution/README.md for the trial tables).
DEFAULT_SCENARIO = "plank-flip"


class DemoError(RuntimeError):
    """The demo could not run (planning failed, a process died, bad arguments)."""


PLAN_INPUTS_FILE = "inputs.sha256"  # beside a cached plan.json: the digest it was planned from


def plan_inputs_digest(problem: Path) -> str:
    """SHA-256 of what a plan of ``problem`` depends on besides the seed: the problem file and
    the model files of its robots and objects (URDF, SRDF, robot.yaml, handles YAML). A handle
    moved in models/objects/ changes it; a cache judged by the problem file's date alone kept
    planning with the old handle."""
    doc = yaml.safe_load(problem.read_text())
    files = [problem]
    for r in doc.get("robots", []):
        if "robot" in r:
            desc = robots.robot(r["robot"])
            files += [desc.urdf, desc.srdf, desc.semantics]
        files += [Path(r[k]) for k in ("urdf", "srdf") if k in r]
    for o in [*doc.get("objects", []), *doc.get("environment", [])]:
        files += [
            marionette.MODELS_DIR / "objects" / f"{o['object']}{ext}" for ext in (".urdf", ".yaml")
        ]
    h = hashlib.sha256()
    for f in files:
        h.update(
            str(f.name).encode() + b"\0" + (f.read_bytes() if f.exists() else b"(missing)") + b"\0"
        )
    return h.hexdigest()


def cached_plan(scenario: Scenario, seed: int, cache_dir: Path, log: Callable[[str], None]) -> Plan:
    """The plan of ``scenario`` for ``seed``: from ``cache_dir`` if planned before from the same
    problem and model files (:func:`plan_inputs_digest`), else planned now with ``marionette
    plan`` (same seed and inputs -> same plan)."""
    out = cache_dir / f"{scenario.problem}-seed{seed}"
    plan_json = out / "plan.json"
    problem = PROBLEMS_DIR / f"{scenario.problem}.yaml"
    digest = plan_inputs_digest(problem)
    stamp = out / PLAN_INPUTS_FILE
    if plan_json.exists() and stamp.exists() and stamp.read_text().strip() == digest:
        log(f"plan: cached {plan_json}")
        return load_plan(plan_json)
    log(f"plan: planning {scenario.problem} with seed {seed} ...")
    t0 = time.perf_counter()
    cmd = [
        sys.executable,
        "-m",
        "marionette.cli",
        "plan",
        str(problem),
        "--out",
        str(out),
        "--seed",
        str(seed),
        "--quiet",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0 or not plan_json.exists():
        raise DemoError(f"planning failed (exit {proc.returncode}):\n{proc.stdout}\n{proc.stderr}")
    stamp.write_text(digest + "\n")
    log(f"plan: planned in {time.perf_counter() - t0:.1f} s -> {plan_json}")
    return load_plan(plan_json)


@dataclass
class Recorder:
    """ROBOT_STATE samples (every ``every``-th) with the simulator's object poses, for plots."""

    model: pin.Model
    client: ControllerClient
    every: int = 5
    utimes: list[int] = field(default_factory=list)
    q: list[np.ndarray] = field(default_factory=list)
    objects: list[dict[str, np.ndarray]] = field(default_factory=list)
    _count: int = 0

    def __post_init__(self) -> None:
        self.client.bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)

    def _on_state(self, msg: Any) -> None:
        self._count += 1
        if self._count % self.every:
            return
        objs = self.client.objects
        poses = (
            {}
            if objs is None
            else {
                o.object_name: np.array([*o.position_world, *o.quaternion_world])
                for o in objs.objects
            }
        )
        self.utimes.append(msg.utime)
        self.q.append(configuration_from_state(self.model, msg))
        self.objects.append(poses)


def _pose_error(X: pin.SE3, X_goal: pin.SE3) -> tuple[float, float]:
    err = X_goal.actInv(X)
    return float(np.linalg.norm(X.translation - X_goal.translation)), float(
        np.degrees(np.linalg.norm(pin.log3(err.rotation)))
    )


def calibrate_encoders(
    scene: Path,
    robot: str,
    sides: tuple[str, ...],
    perturbation: Perturbation | None,
    log: Callable[[str], None],
) -> dict[str, Any]:
    """The encoder offsets of ``sides``' arms from the head camera (thesis 000 ch. 4.2) in the
    robot's ``scene``; with the offsets the perturbation put in, the error left per joint."""

    truth = perturbation.joint_offsets if perturbation is not None else {}
    out: dict[str, Any] = {"arms": [], "encoder_offsets": {}}
    for side in sides:
        arm = calibrate_arm(scene, side, robot, log=log)
        offsets = arm.encoder_offsets()
        summary = arm.summary()
        summary["error_deg"] = {
            j: float(np.degrees(v - truth.get(j, 0.0))) for j, v in offsets.items()
        }
        out["arms"].append(summary)
        out["encoder_offsets"].update(offsets)
        worst = max(summary["error_deg"].items(), key=lambda kv: abs(kv[1]))
        log(
            f"calibration: {side} arm from {arm.views_used} views, residual "
            f"{summary['residual_position_mm']:.1f} mm / {summary['residual_rotation_deg']:.2f}°; offsets "
            + ", ".join(f"{j.split('_')[2]}:{np.degrees(v):+.2f}°" for j, v in offsets.items())
            + f" (worst error {worst[1]:+.2f}° at {worst[0]})"
        )
    return out


def run_demo(
    scenario: Scenario,
    seed: int,
    out_dir: Path,
    speed: float = 1.0,
    cache_dir: Path | None = None,
    log: Callable[[str], None] = print,
    controller_url: str | None = None,
    perturbation: Perturbation | None = None,
    view: bool = False,
    gripper_admittance: bool | None = None,
) -> dict[str, Any]:
    """Runs one trial; returns the report dictionary (``success`` and the measured criteria)
    after writing the report folder ``out_dir``. With ``controller_url`` the trial drives the
    marionette-controller already running there (another machine: ttl=1) instead of starting one.
    ``gripper_admittance``: overrides the scenario's (False: weld-only grasps).
    ``perturbation`` (:mod:`.perturbations`): joint offsets in the simulated robot, the object
    displaced before execution and slipping in the hand during it, camera noise."""
    from marionette.execution.report import write_report

    if scenario.runner is not None:
        if perturbation is not None and perturbation.any:
            raise DemoError(f"{scenario.name} has its own perturbations (no --perturb)")
        return scenario.runner(
            scenario, seed, out_dir, speed=speed, log=log, controller_url=controller_url, view=view
        )
    out_dir.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    plan = cached_plan(
        scenario, seed, cache_dir or (marionette.REPO_ROOT / "reports" / "plans" / "cache"), log
    )
    timings["plan_s"] = time.perf_counter() - t0

    # Controllers (factory) and their checks, before anything moves.
    t1 = time.perf_counter()
    robot = plan_robot(plan)
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    robot_map = PlanRobotMap(plan.doc["problem"]["configuration_layout"], model, robot)
    steps = steps_from_plan(plan)
    if gripper_admittance is None:
        gripper_admittance = scenario.gripper_admittance
    ctx = context_from_plan(plan.doc, robot, model, gripper_admittance=gripper_admittance)
    ctx.visual_servoing = scenario.vision
    specs = build_specs(steps, ctx)
    write_specs(out_dir / "controllers.yaml", steps, specs, plan.doc["problem"]["name"])
    problems = check_specs(steps, specs, ctx, robot_map)
    if problems:
        raise DemoError("controller checks failed:\n  " + "\n  ".join(problems))
    timings["factory_s"] = time.perf_counter() - t1
    log(f"factory: {len(steps)} steps, {len(specs)} controllers -> {out_dir / 'controllers.yaml'}")

    from marionette.planning.graph_factory import graph_from_settings
    from marionette.planning.problem import load_problem

    graph = graph_from_settings(load_problem(plan.doc["problem"]["source"]))
    url = controller_url or private_lcm_url()
    report: dict[str, Any] = {
        "scenario": scenario.name,
        "description": scenario.description,
        "seed": seed,
        "robot": robot,
        "speed": speed,
        "lcm_url": url,
    }
    result: SupervisorResult | None = None
    with ProcessGroup(url, out_dir / "logs") as group, ControllerClient(url) as client:
        # Camera frames (1.5 MB each) stay out of the log: the object poses measured in them are in.
        group.start(
            "lcm-logger",
            ["lcm-logger", f"--lcm-url={url}", "-f", str(out_dir / "run.lcmlog")]
            + (["--channel=^CAMERA_.*", "--invert-channels"] if scenario.vision else []),
        )
        scene = scenario.scene
        if perturbation is not None and perturbation.joint_offsets:
            if controller_url is not None:
                raise DemoError(
                    "joint offsets need the demo's own controller (no --controller-url)"
                )
            scene = scene_with_joint_offsets(
                scene, perturbation.joint_offsets, out_dir / "scene.xml"
            )
        encoder_offsets: dict[str, float] = {}
        if scenario.calibrate_arms and controller_url is None:
            t_cal = time.perf_counter()
            report["calibration"] = calibrate_encoders(
                scene, robot, scenario.calibrate_arms, perturbation, log
            )
            encoder_offsets = report["calibration"]["encoder_offsets"]
            timings["calibration_s"] = time.perf_counter() - t_cal
        if controller_url is None:
            group.start(
                "controller",
                [
                    marionette.BUILD_DIR / "marionette-controller",
                    "--lcm-url",
                    url,
                    "--robot",
                    robot,
                    "--scene",
                    scene,
                    "--speed",
                    str(speed),
                    "--camera-rate",
                    str(scenario.camera_rate if scenario.vision else 0),
                    "--status-rate",
                    "100",
                ]
                + (
                    ["--encoder-offsets", encoder_offsets_argument(encoder_offsets)]
                    if encoder_offsets
                    else []
                ),
            )
        if scenario.vision:
            group.start(
                "perceive",
                [
                    sys.executable,
                    "-m",
                    "marionette.cli",
                    "perceive",
                    "--lcm-url",
                    url,
                    "--robot",
                    robot,
                    "--stats-period",
                    "30",
                    "--quad-decimate",
                    str(scenario.quad_decimate),
                ],
            )
        client.wait_ready(60.0, processes=group)
        if view:  # the browser 3D view of the run (issue #10), stopped with the group
            from marionette.viewer.node import start_viewer

            report["viewer_url"] = start_viewer(group, robot, scenario.scene, log)
        recorder = Recorder(model, client)
        grip = recorder_for(ctx, model)  # the grip force on the jaws (issue 7)
        if grip is not None:
            grip.subscribe(client.bus)
        # Scene set-up: the objects where the problem file puts them (the planner's initial state).
        q0 = plan.doc["problem"]["q_init"]
        for name in robot_map.objects:
            X = robot_map.object_pose(np.array(q0), name)
            if perturbation is not None and name == scenario.object_name:
                X = displaced(X, perturbation.displacement)  # moved after planning
            client.move_object(name, X)
        client.wait_time(0.5)
        q_start = configuration_from_state(model, client.state)

        # Initial-state estimation (§3.2.2) from the encoders and the simulator's object poses.
        t2 = time.perf_counter()
        measured = measured_configuration(
            np.array(q0), robot_map, q_start, {n: client.object_pose(n) for n in robot_map.objects}
        )
        estimate = estimate_state(graph, measured)
        first = first_step_to_run(steps, robot_map, estimate)
        timings["estimation_s"] = time.perf_counter() - t2
        report["estimation"] = {
            "state": estimate.state,
            "residual": estimate.residual,
            "first_step": first,
            "ranking": estimate.ranking[:4],
        }
        log(
            f"estimation: state {estimate.state!r}, residual {estimate.residual:.2e}, "
            f"starting at step {first}/{len(steps)}"
        )

        options = SupervisorOptions(max_joint_velocity=scenario.max_joint_velocity)
        supervisor = Supervisor(
            client, steps, specs, robot_map, options, plan.doc["problem"]["name"]
        )
        timings["references_s"] = supervisor.prepare(first)
        servo = None
        if scenario.vision:
            from marionette.execution.visual_servo import ServoOptions, VisualServo, add_gaze

            t_gaze = time.perf_counter()
            # The camera delivers ~2 frames/s of controller time here (software rendering on shared
            # cores): the servoed steps are slowed down so that several measurements reach them.
            o = supervisor.options
            for step, spec in zip(steps[first:], specs[first:]):
                if any(t.kind == "pbvs" for t in spec.tasks):
                    traj = sample_step(
                        step,
                        robot_map,
                        o.dt_us * 1e-6,
                        o.max_joint_velocity / scenario.servo_slowdown,
                        o.min_step_duration * scenario.servo_slowdown,
                    )
                    compute_references(traj, spec, model)
                    if step.to_state.endswith(("_pregrasp", "_preplace")):
                        # the correction (3 cm/s, 0.3 rad/s) converges at the waypoint, before
                        # the gripper goes into contact
                        dwell(traj, scenario.servo_dwell_s)
                    supervisor.trajectories[step.index] = traj
            add_gaze(
                supervisor.trajectories,
                steps[first:],
                robot_map,
                scenario.object_name,
                robots.robot(robot).camera_frame,
            )
            timings["vision_setup_s"] = time.perf_counter() - t_gaze
            servo_options = (
                ServoOptions()
                if perturbation is None
                else ServoOptions(
                    noise_position_m=perturbation.camera_noise_m,
                    noise_angle_rad=perturbation.camera_noise_rad,
                    seed=perturbation.seed,
                )
            )
            servo = VisualServo(
                client.bus, steps, specs, robot_map, supervisor.trajectories, servo_options
            )
            supervisor.servo = servo
        stop_progress = threading.Event()
        progress = threading.Thread(
            target=_progress, args=(supervisor, stop_progress, log), daemon=True
        )
        progress.start()
        if perturbation is not None and any(perturbation.slip):
            threading.Thread(
                target=_slip,
                args=(
                    supervisor,
                    client,
                    steps,
                    scenario.object_name,
                    perturbation,
                    stop_progress,
                    log,
                ),
                daemon=True,
            ).start()
        t3 = time.perf_counter()
        utime0 = client.utime()
        result = supervisor.run(first)
        timings["execution_wall_s"] = time.perf_counter() - t3
        timings["execution_controller_s"] = (client.utime() - utime0) * 1e-6
        stop_progress.set()
        progress.join(timeout=1.0)
        client.wait_time(1.0)  # the object settles on the table after the release
        final_objects = {n: client.object_pose(n) for n in robot_map.objects}
        status = client.status
        report["controller"] = {
            "mode": status.mode,
            "mode_reason": status.mode_reason,
            "realtime_factor": status.realtime_factor,
            "deadline_misses": status.deadline_misses,
            "num_rejected": status.num_rejected,
            "num_switches": status.num_switches,
            "num_refused_switches": status.num_refused_switches,
        }
        group.check_alive()
    timings["total_s"] = time.perf_counter() - t0

    report.update(
        _criteria(scenario, plan, robot_map, model, result, recorder, q_start, final_objects)
    )
    if grip is not None:
        report["grip"] = _grip_report(grip, scenario, steps, result, out_dir)
        held = [h for g in report["grip"]["grippers"].values() for h in g["held"]]
        within = bool(held) and all(
            abs(h.get("contact_median_n", np.inf) - ADMITTANCE["force_target"])
            <= scenario.grip_tolerance
            for h in held
        )
        report["criteria"]["grip_within_tolerance"] = within
        report["criteria"]["limits"]["grip_n"] = scenario.grip_tolerance
        report["success"] = bool(report["success"] and within)
    report["supervisor"] = {
        "state": result.state,
        "reason": result.reason,
        "steps": len(steps),
        "first_step": first,
        "events": [list(e) for e in result.events],
    }
    report["timings"] = timings
    if perturbation is not None:
        report["perturbation"] = perturbation.to_dict()
    if servo is not None:
        report["vision"] = servo.summary()
    write_report(out_dir, report, scenario, supervisor, result, recorder, model)
    return report


def _grip_report(
    grip: GripForceRecorder,
    scenario: Scenario,
    steps: list,
    result: SupervisorResult,
    out_dir: Path,
) -> dict[str, Any]:
    """Grip force held by each admittance gripper (issue 7): contact force (MuJoCo) and estimate
    over each holding window from 1 s after the switch to admittance to the release (median,
    mean, range); plot grip_force.png."""
    grip.compute()
    target, tolerance = ADMITTANCE["force_target"], scenario.grip_tolerance
    out: dict[str, Any] = {"target_n": target, "plot": "grip_force.png", "grippers": {}}
    spans = {}
    for name in grip.grippers:
        windows = holding_windows(steps, result.records, name)
        spans[name] = windows
        held = []
        for (
            a,
            b,
        ) in windows:  # a window where the estimate never reached the switch counts as failed
            settled = settled_windows(grip, name, [(a, b)], ADMITTANCE["force_threshold"])
            held += (
                [grip.holding_summary(name, *settled[0], target, tolerance)]
                if settled
                else [{"samples": 0, "never_switched": True, "t_from_s": a, "t_to_s": b}]
            )
        out["grippers"][name] = {"holding_windows_s": windows, "held": held}
    grip.plot(out_dir / "grip_force.png", target, spans)
    return out


def _slip(
    supervisor: Supervisor,
    client: ControllerClient,
    steps: list,
    obj: str,
    perturbation: Perturbation,
    stop: threading.Event,
    log: Callable[[str], None],
) -> None:
    """At the start of step ``slip_step`` the object slips in the hands holding it: welds off,
    object moved by the slip twist (its own frame), welds on again where it now is."""
    k = perturbation.slip_step
    while not stop.wait(0.01):
        if supervisor.step_index < k:
            continue
        if supervisor.step_index == k and k < len(steps):
            welds = [
                f"grasp/{g}/{obj}" for g, h in steps[k].grasps.items() if h.split("/")[0] == obj
            ]
            for w in welds:
                client.detach(w)
            client.move_object(obj, slipped(client.object_pose(obj), perturbation.slip))
            for w in welds:
                client.attach(w)
            log(f"perturbation: {obj} slipped in {', '.join(welds) or 'no hand'} at step {k}")
        return


def _progress(supervisor: Supervisor, stop: threading.Event, log: Callable[[str], None]) -> None:
    last = None
    while not stop.wait(0.2):
        now = (supervisor.step_index, supervisor.status)
        if now != last and supervisor.step_index >= 0:
            log(
                f"  [{supervisor.step_index + 1:2d}/{len(supervisor.steps)}] {supervisor.state}: "
                f"{supervisor.status}"
            )
            last = now


def _criteria(
    scenario: Scenario,
    plan: Plan,
    robot_map: PlanRobotMap,
    model: pin.Model,
    result: SupervisorResult,
    recorder: Recorder,
    q_start: np.ndarray,
    final_objects: dict[str, pin.SE3],
) -> dict[str, Any]:
    """The success criteria of ARCHITECTURE.md §Demos, measured."""
    q_goal = np.array(plan.doc["problem"]["q_goal"])
    X_goal = robot_map.object_pose(q_goal, scenario.object_name)
    dp, dtheta = _pose_error(final_objects[scenario.object_name], X_goal)
    criteria: dict[str, Any] = {
        "object_position_error_m": dp,
        "object_angle_error_deg": dtheta,
        "object_within_tolerance": bool(
            dp <= scenario.position_tolerance and dtheta <= scenario.angle_tolerance_deg
        ),
        "fsm_done": result.success,
    }
    ok = criteria["object_within_tolerance"] and result.success
    if scenario.feet:
        data = model.createData()
        pin.framesForwardKinematics(model, data, q_start)
        feet0 = {f: data.oMf[model.getFrameId(f)].translation.copy() for f in scenario.feet}
        moved = 0.0
        base_drop = 0.0
        for q in recorder.q:
            pin.framesForwardKinematics(model, data, q)
            for f in scenario.feet:
                moved = max(
                    moved,
                    float(np.linalg.norm(data.oMf[model.getFrameId(f)].translation - feet0[f])),
                )
            base_drop = max(base_drop, float(q_start[2] - q[2]))
        # The plan itself lowers the base (TALOS bends to reach the table): a fall is the base
        # going lower than the plan's lowest point.
        z_plan = [robot_map.robot_q(q)[2] for q in plan.configurations()]
        planned_drop = max(
            0.0, float(robot_map.robot_q(np.array(plan.doc["problem"]["q_init"]))[2] - min(z_plan))
        )
        criteria["feet_max_displacement_m"] = moved
        criteria["feet_never_moved"] = bool(moved <= scenario.feet_tolerance)
        criteria["base_max_drop_m"] = base_drop
        criteria["base_planned_drop_m"] = planned_drop
        criteria["no_fall"] = bool(base_drop - planned_drop < 0.05)
        ok = ok and criteria["feet_never_moved"] and criteria["no_fall"]
    criteria["limits"] = {
        "position_m": scenario.position_tolerance,
        "angle_deg": scenario.angle_tolerance_deg,
        "feet_m": scenario.feet_tolerance if scenario.feet else None,
    }
    return {"success": bool(ok), "criteria": criteria}
