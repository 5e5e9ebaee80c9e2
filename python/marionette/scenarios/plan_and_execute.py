"""The plan-and-execute scenario kind: plan a manipulation problem (or load the cached plan),
generate one controller per transition, start marionette-controller (MuJoCo) and an LCM logger on
one private LCM URL (:mod:`.harness`), estimate the initial state, run the supervisor FSM, judge
the run against the declared success criteria and write a report folder (report.md, report.json,
plots, controllers.yaml, run.lcmlog).

A scenario of this kind is a declaration only (:class:`PlanAndExecute`): the problem, the scene,
the object whose final pose is judged, the tolerances, and options — vision in the loop (the
controller renders the head camera, ``marionette perceive`` publishes the object's pose, the head
looks at it and the steps that approach or place it are servoed on the measured pose,
:mod:`marionette.execution.visual_servo`), gripper admittance (close on the handle, hold 5 N,
release; the grip measured on the jaws), arms whose encoder offsets the head camera calibrates
before the controller starts (:mod:`marionette.perception.arm_calibration`; the controller runs
with ``--encoder-offsets``). It is written in Python (``plank_flip.py``, ``ur10_box.py``) or in a
YAML file (:mod:`.declarations`). ``RunOptions.perturbation`` (:mod:`.perturbations`) adds seeded
perturbations; without it the objects start where the problem file says.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pinocchio as pin
import yaml

import marionette
from marionette import channels, lcmt_robot_state, robots
from marionette.control.client import ControllerClient, configuration_from_state
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.dry_run import dry_run
from marionette.execution.estimation import (
    estimate_state,
    first_step_to_run,
    measured_configuration,
    sensed_object_poses,
)
from marionette.execution.factory import (
    ADMITTANCE,
    FactoryContext,
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
from marionette.execution.grip_monitor import GripMonitor, GripMonitorNode
from marionette.execution.plan_steps import PlanRobotMap, Step, plan_robot, steps_from_plan
from marionette.execution.references import StepTiming, grip_change_s
from marionette.execution.supervisor import JOURNAL_NAME as SUPERVISOR_JOURNAL
from marionette.execution.supervisor import (
    Supervisor,
    SupervisorOptions,
    SupervisorResult,
    prepare_trajectories,
)
from marionette.execution.visual_servo import (
    Lean,
    ObjectView,
    gaze_rewrite,
    handover_approaches,
    looks_before_approach,
    servoed_tasks,
)
from marionette.perception.arm_calibration import calibrate_arm, encoder_offsets_argument
from marionette.perception.calibration import CalibrationError
from marionette.planning.path import Plan
from marionette.scenarios.base import (
    Criterion,
    RunOptions,
    Scenario,
    ScenarioError,
)
from marionette.scenarios.harness import Processes, harness
from marionette.scenarios.perturbations import (
    Perturbation,
    acting_on,
    displaced,
    missing_joints,
    scene_with_joint_offsets,
    slipped,
)
from marionette.scenarios.plan_cache import PlanningFailed, cached_plan, default_cache_dir

if TYPE_CHECKING:
    from marionette.planning.problem import ManipulationProblem

PROBLEMS_DIR = Path(marionette.__file__).resolve().parent / "planning" / "problems"
SCENES_DIR = marionette.MODELS_DIR / "scenes"
# [s of controller time] how long the camera looks at the objects before the initial-state
# estimation: a few frames (TALOS' head, at its start posture, does not see plank-flip's plank:
# the estimation then takes it where the plan starts it, and says so)
START_LOOK_S = 1.0


def problem_names(problem: Path) -> tuple[str, list[str]]:
    """The robot a planning problem names (``robots: [{robot: NAME}]``: the controller's
    ``--robot``) and its movable objects. ScenarioError when the file cannot be read or names no
    single bundled robot."""
    try:
        doc = yaml.safe_load(Path(problem).read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise ScenarioError(f"cannot read the problem {problem}: {e}") from e
    robots_ = [r["robot"] for r in doc.get("robots", []) or [] if "robot" in r]
    if len(robots_) != 1:
        raise ScenarioError(
            f"{problem}: a plan-and-execute scenario needs exactly one robot given by name "
            f"(robots: [{{robot: NAME}}]), found {robots_ or 'none'}"
        )
    objects = [o.get("name", o.get("object")) for o in doc.get("objects", []) or []]
    return robots_[0], objects


@dataclass(frozen=True, kw_only=True)
class PlanAndExecute(Scenario):
    """Plan ``problem``, execute the plan in ``scene``, judge where ``object_name`` ends up
    against the plan's goal. ``robot`` defaults to the problem's (and must agree with it)."""

    KIND: ClassVar[str] = "plan-and-execute"
    OPTIONS: ClassVar[tuple[str, ...]] = (
        "perturbation",
        "gripper_admittance",
        "cache_dir",
        "dry_run",
    )

    robot: str = ""
    problem: Path
    object_name: str
    max_joint_velocity: float  # [rad/s] time law of the planned paths
    position_tolerance: float = 0.01  # [m]   object final pose vs the plan's goal
    angle_tolerance_deg: float = 5.0
    feet: tuple[str, ...] = ()  # frames that must never move (humanoid)
    feet_tolerance: float = 0.005  # [m]
    fall_margin: float = 0.05  # [m] a fall: the base this far below the plan's lowest point
    vision: bool = False  # camera + perception + PBVS on the carried object (ch. 5)
    camera_rate: float = 5.0  # [Hz of controller time] head camera frames with vision
    servo_slowdown: float = 3.0  # servoed steps run this much slower: more frames to servo on
    quad_decimate: float = 2.0  # perceive's AprilTag decimation (1: small or oblique tags too)
    servo_dwell_s: float = 2.0  # a servoed step waits this long at its pre-grasp / pre-placement
    # gripper_admittance tasks on the grippers with a joint (close on the handle, hold 5 N,
    # release), and the grip force measured on the jaws as a success criterion (± grip_tolerance).
    gripper_admittance: bool = False
    grip_tolerance: float = 1.0  # [N]
    # The grippers hold objects by friction alone; False: the simulator welds each grasp (for
    # grippers whose fingers cannot hold their objects yet; a debugging aid otherwise).
    friction_grasps: bool = False
    # Arms whose encoder offsets the head camera calibrates before execution (thesis 000 ch. 4.2,
    # :mod:`marionette.perception.arm_calibration`); the controller then corrects its encoders.
    calibrate_arms: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("max_joint_velocity", "position_tolerance", "angle_tolerance_deg"):
            if not getattr(self, name) > 0:
                raise ScenarioError(f"{self.name}: {name} must be > 0, got {getattr(self, name)}")
        for name in ("feet_tolerance", "fall_margin", "grip_tolerance", "camera_rate"):
            if not getattr(self, name) > 0:
                raise ScenarioError(f"{self.name}: {name} must be > 0, got {getattr(self, name)}")
        if self.servo_slowdown < 1 or self.quad_decimate < 1 or self.servo_dwell_s < 0:
            raise ScenarioError(
                f"{self.name}: need servo_slowdown >= 1, quad_decimate >= 1, servo_dwell_s >= 0"
            )
        for side in self.calibrate_arms:
            if side not in ("left", "right"):
                raise ScenarioError(
                    f"{self.name}: calibrate_arms takes left and right, got {side!r}"
                )
        if not Path(self.scene).is_file():
            raise ScenarioError(f"{self.name}: no scene file {self.scene}")
        robot, objects = problem_names(self.problem)
        if self.object_name not in objects:
            raise ScenarioError(
                f"{self.name}: object {self.object_name!r} is not a movable object of the "
                f"problem {self.problem} ({', '.join(map(str, objects)) or 'none'})"
            )
        if self.robot and self.robot != robot:
            raise ScenarioError(
                f"{self.name}: robot {self.robot!r} but the problem {self.problem} plans for "
                f"{robot!r}"
            )
        object.__setattr__(self, "robot", robot)

    def criteria(self) -> tuple[Criterion, ...]:
        out = [
            Criterion(
                "object_within_tolerance",
                f"{self.object_name} final pose vs the plan's goal",
                f"{self.position_tolerance * 1e3:g} mm / {self.angle_tolerance_deg:g}°",
            ),
            Criterion("fsm_done", "supervisor FSM reached `done`", "every step done"),
        ]
        if self.feet:
            out += [
                Criterion(
                    "feet_never_moved",
                    f"{', '.join(self.feet)} displacement (max)",
                    f"{self.feet_tolerance * 1e3:g} mm",
                ),
                Criterion(
                    "no_fall",
                    "base height drop below the plan's lowest point",
                    f"< {self.fall_margin * 1e3:g} mm",
                ),
            ]
        if self.gripper_admittance:
            out.append(
                Criterion(
                    "grip_within_tolerance",
                    "grip force on the jaws, median over each hold (MuJoCo contacts)",
                    f"{ADMITTANCE['force_target']:g} ± {self.grip_tolerance:g} N",
                )
            )
        return tuple(out)

    def declared_settings(self) -> dict[str, Any]:
        """The kind's declaration fields (:mod:`.declarations` reads them back)."""
        return {
            "problem": _named(Path(self.problem), PROBLEMS_DIR, ".yaml"),
            "object": self.object_name,
            "max_joint_velocity": self.max_joint_velocity,
            "tolerances": {
                "position_m": self.position_tolerance,
                "angle_deg": self.angle_tolerance_deg,
                "feet_m": self.feet_tolerance,
                "fall_m": self.fall_margin,
                "grip_n": self.grip_tolerance,
            },
            "feet": list(self.feet),
            "gripper_admittance": self.gripper_admittance,
            "friction_grasps": self.friction_grasps,
            "calibrate_arms": list(self.calibrate_arms),
            "vision": (
                {
                    "camera_rate_hz": self.camera_rate,
                    "servo_slowdown": self.servo_slowdown,
                    "quad_decimate": self.quad_decimate,
                    "servo_dwell_s": self.servo_dwell_s,
                }
                if self.vision
                else None
            ),
        }

    def document(self) -> dict[str, Any]:
        """The declaration as a YAML document (:func:`.declarations.declaration_from_document`
        reads it back to an equal scenario)."""
        doc: dict[str, Any] = {
            "kind": self.KIND,
            "name": self.name,
            "description": self.description,
            "seed_experiment": self.seed_experiment,
            "robot": self.robot,
            "scene": _named(Path(self.scene), SCENES_DIR, ".xml"),
            "seed": self.seed,
            **self.declared_settings(),
        }
        if doc["vision"] is None:
            del doc["vision"]
        return doc

    def admittance_in(self, options: RunOptions) -> bool:
        """Whether a trial with ``options`` gives its grippers admittance tasks."""
        if options.gripper_admittance is None:
            return self.gripper_admittance
        return options.gripper_admittance

    def friction_grasps_in(self, options: RunOptions) -> bool:
        """Whether a trial with ``options`` holds objects by friction: the scenario's grippers
        can, and their admittance squeezes (without it the grasps are welds)."""
        return self.friction_grasps and self.admittance_in(options)

    def check_options(self, options: RunOptions) -> None:
        super().check_options(options)
        p = options.perturbation
        # In-hand perturbations act on the grasps that feel them (perturbations.acting_on): the
        # slip on welds, a push or a friction change on friction grasps. Refused when those
        # asked include none this trial's grasps feel.
        friction = self.friction_grasps_in(options)
        pushed = p is not None and any(p.push)
        on_friction = pushed or (p is not None and bool(p.carry_friction))
        on_welds = p is not None and any(p.slip)
        if on_friction and not on_welds and not friction:
            what = "a push" if pushed else "a friction change"
            raise ScenarioError(
                f"{self.name} welds its grasps: {what} on the held object tests a friction "
                "grasp (a weld would not feel it; add --gripper-admittance)"
            )
        if on_welds and not on_friction and friction:
            raise ScenarioError(
                f"{self.name} holds its objects by friction: the in-hand slip moves welded "
                "grasps only (push the object instead, push_n=N, or add "
                "--no-gripper-admittance for welded grasps)"
            )
        if p is not None and p.joint_offsets:
            if options.controller_url is not None:
                raise ScenarioError(
                    "joint offsets need the demo's own controller (no --controller-url)"
                )
            missing = missing_joints(self.scene, sorted(p.joint_offsets))
            if missing:
                raise ScenarioError(
                    f"{self.name}: the perturbation offsets joints its scene does not have "
                    f"({', '.join(missing)})"
                )

    def trial(
        self, seed: int, out_dir: Path, options: RunOptions, report: dict[str, Any]
    ) -> dict[str, Any]:
        return run_plan_and_execute(self, seed, out_dir, options, report)

    def summary(self, report: dict[str, Any], trial_seed: int) -> str:
        if "criteria" not in report:  # stopped before execution (refused plan, calibration)
            return f"FAILURE (seed {trial_seed}): {report.get('stopped', 'stopped')}"
        c = report["criteria"]
        return (
            f"{'SUCCESS' if report['success'] else 'FAILURE'} (seed {trial_seed}): "
            f"{self.object_name} {c['object_position_error_m'] * 1e3:.1f} mm / "
            f"{c['object_angle_error_deg']:.2f}° from the goal"
            + (
                f", feet moved {c['feet_max_displacement_m'] * 1e3:.2f} mm"
                if "feet_max_displacement_m" in c
                else ""
            )
            + ("" if c["fsm_done"] else f"; {self.failure_reason(report)}")
        )

    def failure_reason(self, report: dict[str, Any]) -> str:
        if "criteria" not in report:
            return str(report.get("stopped", "stopped"))
        c = report["criteria"]
        if not c["fsm_done"]:
            return f"supervisor: {report['supervisor']['reason']}"
        reasons = []
        if not c["object_within_tolerance"]:
            reasons.append(
                f"object {c['object_position_error_m'] * 1e3:.1f} mm / "
                f"{c['object_angle_error_deg']:.1f}° from the goal"
            )
        if c.get("feet_never_moved") is False:
            reasons.append(f"feet moved {c['feet_max_displacement_m'] * 1e3:.1f} mm")
        if c.get("no_fall") is False:
            reasons.append("fell")
        if c.get("grip_within_tolerance") is False:
            reasons.append("grip force out of tolerance")
        return "; ".join(reasons)


def _named(path: Path, folder: Path, suffix: str) -> str:
    """A bundled file by its name (``ur10_box``), any other by its path."""
    p = path.resolve()
    return p.stem if p.parent == folder.resolve() and p.suffix == suffix else str(p)


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
            f"{summary['residual_position_mm']:.1f} mm / "
            f"{summary['residual_rotation_deg']:.2f}°; offsets "
            + ", ".join(f"{j.split('_')[2]}:{np.degrees(v):+.2f}°" for j, v in offsets.items())
            + f" (worst error {worst[1]:+.2f}° at {worst[0]})"
        )
    return out


def run_plan_and_execute(
    scenario: PlanAndExecute,
    seed: int,
    out_dir: Path,
    options: RunOptions,
    report: dict[str, Any],
) -> dict[str, Any]:
    """One trial of ``scenario`` planned with ``seed`` (:meth:`.base.Scenario.run` calls it):
    fills ``report`` (``success`` and the measured criteria), writes the report folder and
    returns it. With ``options.controller_url`` the trial drives the marionette-controller
    already running there (another machine: ttl=1) instead of starting one.
    ``options.gripper_admittance`` overrides the scenario's (False: weld-only grasps).
    ``options.perturbation`` (:mod:`.perturbations`): joint offsets in the simulated robot, the
    object displaced before execution and slipping in the hand during it, camera noise."""
    from marionette.scenarios.plan_and_execute_report import write_report

    log, perturbation, controller_url = options.log, options.perturbation, options.controller_url
    if perturbation is not None:
        perturbation, left_out = acting_on(perturbation, scenario.friction_grasps_in(options))
        if left_out is not None:
            log(f"perturbation: {left_out}")
    timings: dict[str, float] = {}
    report["timings"] = timings  # filled as the trial goes (a partial report has them too)
    t0 = time.perf_counter()
    try:
        plan = cached_plan(
            Path(scenario.problem), seed, options.cache_dir or default_cache_dir(), log
        )
    except PlanningFailed as e:
        raise ScenarioError(str(e)) from e
    timings["plan_s"] = time.perf_counter() - t0

    # Controllers (factory) and their checks, before anything moves.
    t1 = time.perf_counter()
    robot = plan_robot(plan)
    if robot != scenario.robot:
        raise ScenarioError(f"the plan is for {robot!r}, the scenario for {scenario.robot!r}")
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    robot_map = PlanRobotMap(plan.doc["problem"]["configuration_layout"], model, robot)
    steps = steps_from_plan(plan)
    ctx = context_from_plan(
        plan.doc, robot, model, gripper_admittance=scenario.admittance_in(options)
    )
    ctx.visual_servoing = scenario.vision
    if scenario.friction_grasps_in(options):
        jaws = robots.robot(robot).jaws
        grasping = sorted({g for step in steps for g in (*step.grasps, *step.grasps_to)})
        for gripper in grasping:  # the grippers the plan grasps with (not a drill beside them)
            if gripper not in ctx.gripper_joints or gripper not in jaws:
                raise ScenarioError(
                    f"{scenario.name}: friction_grasps, but gripper {gripper} cannot hold by "
                    "friction (it needs a finger joint with open_position and closed_position "
                    "and its jaws in robot.yaml); set friction_grasps: false for welded grasps"
                )
    specs = build_specs(steps, ctx)
    write_specs(out_dir / "controllers.yaml", steps, specs, plan.doc["problem"]["name"])
    problems = check_specs(steps, specs, ctx, robot_map)
    if problems:
        raise ScenarioError("controller checks failed:\n  " + "\n  ".join(problems))
    timings["factory_s"] = time.perf_counter() - t1
    log(f"factory: {len(steps)} steps, {len(specs)} controllers -> {out_dir / 'controllers.yaml'}")

    # The references the supervisor will stream, within the joints' bounds (re-timed where the
    # gaze made a step too fast), and the dry run of the controllers on them.
    t_ref = time.perf_counter()
    supervisor_options = SupervisorOptions(
        max_joint_velocity=scenario.max_joint_velocity,
        simulated_grasps=not scenario.friction_grasps_in(options),
    )
    handovers = scenario.friction_grasps_in(options)  # servoed (ServoOptions.handovers)
    timing = _servo_timing(scenario, handovers) if scenario.vision else None
    from marionette.planning.problem import load_problem

    problem = load_problem(plan.doc["problem"]["source"])  # the lean's checker and the graph
    rewrites = []
    if scenario.vision:
        desc = robots.robot(robot)
        if desc.camera_frame is None:
            raise ScenarioError(f"{scenario.name}: vision needs a camera; robot {robot} has none")
        if not desc.calibration_head_joints:
            raise ScenarioError(
                f"{scenario.name}: the gaze needs the joints that aim the camera; declare them "
                f"as calibration.head_joints in models/{robot}/robot.yaml"
            )
        rewrites.append(
            gaze_rewrite(
                robot_map,
                scenario.object_name,
                desc.camera_frame,
                desc.calibration_head_joints,
                _lean_for_view(robot, scenario.object_name, steps, specs, problem, robot_map, ctx),
            )
        )
    try:
        trajectories = prepare_trajectories(
            steps, specs, robot_map, supervisor_options, 0, timing, rewrites
        )
    except ValueError as e:  # a step no re-timing brings within the joints' bounds
        raise ScenarioError(f"references: {e}") from None
    timings["references_s"] = time.perf_counter() - t_ref
    retimed = [(i, t) for i, t in trajectories.items() if t.retimed > 1.0]
    if retimed:
        log(
            "references: re-timed "
            + ", ".join(f"step {i} x{t.retimed:.2f} ({t.retimed_for})" for i, t in retimed)
            + " to keep the streamed velocities within the joints' bounds"
        )
    if options.dry_run:
        t_dry = time.perf_counter()
        log("dry run: the controllers played on the plan (kinematic controller) ...")
        verdict = dry_run(
            robot,
            steps,
            specs,
            robot_map,
            trajectories,
            supervisor_options,
            log_dir=out_dir / "logs",
            gripper_frames=ctx.gripper_frames,
        )
        timings["dry_run_s"] = time.perf_counter() - t_dry
        report["dry_run"] = verdict.to_dict()
        log(
            f"dry run: {'passed' if verdict.ok else 'REFUSED'} in {verdict.wall_s:.1f} s "
            f"({verdict.controller_s:.1f} s of controller time)"
            + ("" if verdict.ok else f": {verdict.reason}")
        )
        if not verdict.ok:
            return _refused(report, out_dir, f"the dry run refused the plan: {verdict.reason}")

    from marionette.planning.graph_factory import graph_from_settings

    graph = graph_from_settings(problem)
    scene = scenario.scene
    if perturbation is not None and perturbation.joint_offsets:  # checked by check_options
        scene = scene_with_joint_offsets(scene, perturbation.joint_offsets, out_dir / "scene.xml")
    encoder_offsets: dict[str, float] = {}
    if scenario.calibrate_arms and controller_url is None:
        t_cal = time.perf_counter()
        try:
            report["calibration"] = calibrate_encoders(
                scene, robot, scenario.calibrate_arms, perturbation, log
            )
        except CalibrationError as e:
            timings["calibration_s"] = time.perf_counter() - t_cal
            return _refused(report, out_dir, f"encoder calibration failed: {e}")
        encoder_offsets = report["calibration"]["encoder_offsets"]
        timings["calibration_s"] = time.perf_counter() - t_cal
    processes = Processes(
        robot,
        scene,
        camera_rate=scenario.camera_rate if scenario.vision else 0.0,
        sim_args=(
            ("--encoder-offsets", encoder_offsets_argument(encoder_offsets))
            if encoder_offsets
            else ()
        ),
        perceive=(
            (
                "--robot",
                robot,
                "--stats-period",
                "30",
                "--quad-decimate",
                str(scenario.quad_decimate),
            )
            if scenario.vision
            else None
        ),
        view_scene=scenario.scene,
    )
    result: SupervisorResult | None = None
    with harness(out_dir, processes, options, report) as run:
        client = run.client
        recorder = Recorder(model, client)
        grip = recorder_for(ctx, model)  # the grip force on the jaws
        if grip is not None:
            grip.subscribe(client.bus)
        # An admittance gripper whose fingers close on nothing fails the step (grasp_lost).
        grip_monitor = (
            GripMonitorNode(client.bus, GripMonitor(ctx.gripper_joints), steps)
            if ctx.gripper_joints
            else None
        )
        # Scene set-up: the objects where the problem file puts them (the planner's initial state).
        q0 = plan.doc["problem"]["q_init"]
        for name in robot_map.objects:
            X = robot_map.object_pose(np.array(q0), name)
            if perturbation is not None and name == scenario.object_name:
                X = displaced(X, perturbation.displacement)  # moved after planning
            client.move_object(name, X)
        client.wait_time(0.5)
        q_start = configuration_from_state(model, client.state)

        # Initial-state estimation (§3.2.2) from the encoders and what the camera sees.
        t2 = time.perf_counter()
        sensed = sensed_object_poses(
            client, robot_map.objects, START_LOOK_S if scenario.vision else 0.0, log
        )
        measured = measured_configuration(np.array(q0), robot_map, q_start, sensed)
        estimate = estimate_state(graph, measured)
        first = first_step_to_run(steps, robot_map, estimate)
        timings["estimation_s"] = time.perf_counter() - t2
        report["estimation"] = {
            "state": estimate.state,
            "residual": estimate.residual,
            "objects_sensed": sorted(sensed),
            "first_step": first,
            "ranking": estimate.ranking[:4],
        }
        log(
            f"estimation: state {estimate.state!r}, residual {estimate.residual:.2e}, "
            f"starting at step {first}/{len(steps)}"
        )

        supervisor = Supervisor(
            client, steps, specs, robot_map, supervisor_options, plan.doc["problem"]["name"]
        )
        supervisor.timing = timing or supervisor.timing
        supervisor.rewrites = rewrites
        supervisor.journal = out_dir / SUPERVISOR_JOURNAL
        if first == 0:  # else the first step run ramps the gaze in: sampled again
            supervisor.trajectories = trajectories
        timings["references_s"] += supervisor.prepare(first)
        servo = None
        if scenario.vision:
            from marionette.execution.visual_servo import ServoOptions, VisualServo

            servo_options = (
                ServoOptions(handovers=handovers)
                if perturbation is None
                else ServoOptions(
                    noise_position_m=perturbation.camera_noise_m,
                    noise_angle_rad=perturbation.camera_noise_rad,
                    seed=perturbation.seed,
                    handovers=handovers,
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
        if perturbation is not None and (any(perturbation.push) or perturbation.carry_friction):
            _in_background(
                _during_first_carry,
                supervisor,
                client,
                steps,
                specs,
                robot,
                scenario.object_name,
                perturbation,
                stop_progress,
                log,
            )
        if perturbation is not None and any(perturbation.slip):
            _in_background(
                _slip,
                supervisor,
                client,
                steps,
                scenario.object_name,
                perturbation,
                stop_progress,
                log,
            )
        t3 = time.perf_counter()
        utime0 = client.utime()
        result = supervisor.run(first)
        timings["execution_wall_s"] = time.perf_counter() - t3
        timings["execution_controller_s"] = (client.utime() - utime0) * 1e-6
        stop_progress.set()
        progress.join(timeout=1.0)
        client.wait_time(1.0)  # the object settles on the table after the release
        final_objects = {n: client.object_pose(n) for n in robot_map.objects}
        if grip_monitor is not None:
            report["grasps_lost"] = [
                {
                    "controller_time_s": utime * 1e-6,
                    "gripper": lost.gripper,
                    "detail": lost.describe(),
                }
                for utime, lost in grip_monitor.events
            ]
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


def _lean_for_view(
    robot: str,
    obj: str,
    steps: list[Step],
    specs: list[ControllerSpec],
    problem: ManipulationProblem,
    robot_map: PlanRobotMap,
    ctx: FactoryContext,
) -> Lean | None:
    """What the gaze needs to lean the torso where the servo looks (:func:`gaze_rewrite`); None
    for a robot whose camera declares no lean joints. The lean keeps every hand where the plan
    has it (a free arm would otherwise swing with the torso: a left hand went into the table)
    and adds no collision the plan's configuration did not have (the planner's checker)."""
    from marionette.perception.objects import tagged_bodies_from_semantics
    from marionette.perception.visibility import LineOfSight, ViewLimits
    from marionette.planning.collision import CollisionChecker

    desc = robots.robot(robot)
    camera = desc.cameras[0] if desc.cameras else None
    if camera is None or not camera.lean_joints or not desc.calibration_head_joints:
        return None
    model, geom = robots.load_pinocchio(robot, with_collision=True)
    (body,) = tagged_bodies_from_semantics(robots.load_object(obj).semantics)
    view = ObjectView(
        model,
        camera.frame,
        body,
        camera.intrinsics(),
        LineOfSight(model, geom, None, camera.frame),
        # 32 mm tags are found up to ~1.2 m and 60° off the axis on 640 x 480 frames. A tag
        # predicted 15 px inside the image's edge was not seen in a placement where the plank
        # sat centimetres off its plan (the grasp and the slip): 40 px (3.5 cm at 0.55 m) first.
        tuple(
            ViewLimits(
                margin_px=20.0,
                corner_margin_px=margin,
                min_depth=0.2,
                max_depth=1.2,
                max_angle_deg=60.0,
            )
            for margin in (40.0, 15.0)
        ),
    )
    # where the servo uses what the camera sees: the servoed steps, and the step before an
    # approach to an object at rest (the reaching hand may hide it during the approach). Not a
    # hand-over's approach (servoed or not: ``servoed_tasks`` leaves them out here): leaning the
    # torso there moves the hand that holds the object out in front with it (plan 116: 0.35 rad,
    # the feet 31 mm off their tasks and the holding hand 70 mm, the step's end check failed);
    # the servo takes what the head sees unleaned.
    looking = set(servoed_tasks(steps, specs)) | looks_before_approach(steps, specs)
    held = {}
    for step, spec in zip(steps, specs):
        if step.index in looking:
            posture = min((t.priority for t in spec.tasks if t.kind == "posture"), default=None)
            tasks = [
                t
                for t in spec.tasks
                if t.kind != "posture" and (posture is None or t.priority < posture)
            ]
            framed = {t.frame for t in tasks}
            tasks += [
                TaskSpec(f"{frame}_kept", "se3", 0, frame=frame)
                for frame in sorted(set(ctx.gripper_frames.values()) - framed)
            ]
            held[step.index] = tasks
    checker = CollisionChecker(problem, backend="python")

    def allowed(q_plan: np.ndarray, q_robot: np.ndarray) -> bool:
        q = np.array(q_plan, dtype=float)
        q[robot_map.idx] = q_robot
        return set(checker.colliding_pairs(q)) <= set(checker.colliding_pairs(q_plan))

    return Lean(view, desc.calibration_head_joints, camera.lean_joints[0], held, allowed)


def _refused(report: dict[str, Any], out_dir: Path, reason: str) -> dict[str, Any]:
    """The trial fails before anything moves (a plan the dry run refuses, a calibration that
    cannot see the wrists): its report says why, with what was measured until then."""
    from marionette.scenarios.plan_and_execute_report import write_refusal

    report["success"] = False
    report["stopped"] = reason
    write_refusal(out_dir, report)
    return report


def _servo_timing(scenario: PlanAndExecute, handovers: bool) -> Callable[[Any, Any], StepTiming]:
    """How the servoed steps (a pbvs task, a hand-over's approach) are played: ``servo_slowdown``
    slower than the plan's time law (the camera delivers ~2 frames/s of controller time here,
    software rendering on shared cores: several measurements must reach each servoed step), then,
    at a pre-grasp / pre-placement, a ``servo_dwell_s`` wait for the correction (3 cm/s,
    0.3 rad/s) to converge before the gripper goes into contact."""

    def timing(step: Any, spec: Any) -> StepTiming:
        servoed_handover = handovers and handover_approaches(step, spec)
        if not any(t.kind == "pbvs" for t in spec.tasks) and not servoed_handover:
            return StepTiming()
        waypoint = step.to_state.endswith(("_pregrasp", "_preplace"))
        return StepTiming(scenario.servo_slowdown, scenario.servo_dwell_s if waypoint else 0.0)

    return timing


def _grip_report(
    grip: GripForceRecorder,
    scenario: PlanAndExecute,
    steps: list,
    result: SupervisorResult,
    out_dir: Path,
) -> dict[str, Any]:
    """Grip force held by each admittance gripper: contact force (MuJoCo) and estimate
    over each holding window from 1 s after the switch to admittance to the release (median,
    mean, range), and how far the scenario's object moved in the hand over it; plot
    grip_force.png."""
    grip.compute()
    target, tolerance = ADMITTANCE["force_target"], scenario.grip_tolerance
    out: dict[str, Any] = {"target_n": target, "plot": "grip_force.png", "grippers": {}}
    spans = {}
    for name in grip.grippers:
        windows = holding_windows(steps, result.records, name, grip.t[-1] if grip.t else None)
        spans[name] = windows
        held = []
        for (
            a,
            b,
        ) in windows:  # a window where the estimate never reached the switch counts as failed
            settled = settled_windows(grip, name, [(a, b)], ADMITTANCE["force_threshold"])
            if not settled:
                held.append({"samples": 0, "never_switched": True, "t_from_s": a, "t_to_s": b})
                continue
            summary = grip.holding_summary(name, *settled[0], target, tolerance)
            motion = grip.hold_motion(name, scenario.object_name, *settled[0])
            if motion is not None:  # the object's motion in the hand while it is held
                summary["object_motion_mm"] = motion[0] * 1e3
                summary["object_rotation_deg"] = math.degrees(motion[1])
            held.append(summary)
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
    """At the start of step ``slip_step`` (None: :func:`last_carry_step`) the object slips in the
    hands holding it: welds off, object moved by the slip twist (its own frame), welds on again
    where it now is."""
    k = perturbation.slip_step
    if k is None:
        k = last_carry_step(steps, obj)
        if k is None:
            log(f"perturbation: no step carries {obj}: no slip")
            return
    if not _reached(supervisor, k, stop, 0.01) or k >= len(steps):
        return
    welds = [f"grasp/{g}/{obj}" for g in sorted(_holders(steps[k], obj))]
    for w in welds:
        client.detach(w)
    client.move_object(obj, slipped(client.object_pose(obj), perturbation.slip))
    for w in welds:
        client.attach(w)
    log(f"perturbation: {obj} slipped in {', '.join(welds) or 'no hand'} at step {k}")


def _in_background(target: Callable[..., None], *args: Any) -> None:
    """Runs a perturbation beside the supervisor (it watches the supervisor's step)."""
    threading.Thread(target=target, args=args, daemon=True).start()


def _reached(supervisor: Supervisor, k: int, stop: threading.Event, poll_s: float) -> bool:
    """Waits until the supervisor runs step ``k`` or later: True when it runs ``k``, False when
    it went past it (or ``stop`` was set) unseen."""
    while not stop.wait(poll_s):
        if supervisor.step_index >= k:
            return supervisor.step_index == k
    return False


def _holders(step, obj: str) -> frozenset[str]:
    """The grippers that hold ``obj`` all along ``step``."""
    return frozenset(g for g, h in step.grasps.items() if h.split("/")[0] == obj)


def last_carry_step(steps: list, obj: str) -> int | None:
    """The start of ``obj``'s last carry: the first motion step (no grasp created or released)
    of the last run of steps that hold it in the same hands before it is let go — after a
    hand-over, the carry to the placement; the placement servo (§5.3.1) is what can correct a
    slip there. None when no step holds it."""
    held = [i for i, s in enumerate(steps) if _holders(s, obj)]
    if not held:
        return None
    last = held[-1]
    first = last
    while first > 0 and _holders(steps[first - 1], obj) == _holders(steps[last], obj):
        first -= 1
    return next((i for i in range(first, last + 1) if steps[i].kind == "motion"), first)


def _during_first_carry(
    supervisor: Supervisor,
    client: ControllerClient,
    steps: list,
    specs: list,
    robot: str,
    obj: str,
    perturbation: Perturbation,
    stop: threading.Event,
    log: Callable[[str], None],
) -> None:
    """In the first step that carries ``obj`` in a hand, once the grip has settled (the step's
    lead-in, :func:`references.grip_change_s`): the object's friction becomes
    ``carry_friction`` (when set), and ``push_delay_s`` later it is pushed by ``push`` [N] for
    ``push_s`` (when set). The physics decides whether the grip holds it."""
    k = next((i for i, s in enumerate(steps) if i > 0 and _holders(s, obj)), None)
    if k is None:
        log(f"perturbation: no step carries {obj}: no push, no friction change")
        return
    if not _reached(supervisor, k, stop, 0.002):
        return
    client.wait_time(grip_change_s(steps[k], steps[k - 1], specs[k], robot))
    if stop.is_set() or supervisor.step_index != k:
        return
    if perturbation.carry_friction:
        client.set_friction(obj, perturbation.carry_friction)
        log(f"perturbation: {obj}'s friction set to {perturbation.carry_friction:g} in step {k}")
    if not any(perturbation.push):
        return
    client.wait_time(perturbation.push_delay_s)
    if stop.is_set() or supervisor.step_index != k:
        return
    client.push_object(obj, perturbation.push, perturbation.push_s)
    log(
        f"perturbation: {obj} pushed with {np.linalg.norm(perturbation.push):.1f} N for "
        f"{perturbation.push_s:g} s in step {k}"
    )


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
    scenario: PlanAndExecute,
    plan: Plan,
    robot_map: PlanRobotMap,
    model: pin.Model,
    result: SupervisorResult,
    recorder: Recorder,
    q_start: np.ndarray,
    final_objects: dict[str, pin.SE3],
) -> dict[str, Any]:
    """The success criteria (:meth:`PlanAndExecute.criteria`), measured."""
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
        criteria["no_fall"] = bool(base_drop - planned_drop < scenario.fall_margin)
        ok = ok and criteria["feet_never_moved"] and criteria["no_fall"]
    criteria["limits"] = {
        "position_m": scenario.position_tolerance,
        "angle_deg": scenario.angle_tolerance_deg,
        "feet_m": scenario.feet_tolerance if scenario.feet else None,
    }
    return {"success": bool(ok), "criteria": criteria}
