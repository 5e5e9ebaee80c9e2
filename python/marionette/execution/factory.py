"""The controller factory (thesis 000 §3.2.5.1, §3.3.6 "Agimus-SoT"): one ControllerSpec per
step of a plan, with the three task groups of §3.2.5.1, by priority:

1. balance/base tasks, from the constraints that hold in every state (``graph_constraints``):
   a frame fixed in the world (TALOS feet) -> ``se3`` holding it; the centre of mass -> ``com``
   following the planned CoM; locked joints are left to the posture task;
2. transition-specific tasks: every gripper that holds, takes or leaves a handle in the step's
   transition -> ``se3`` following its planned pose; a second gripper on the object another one
   already holds -> ``relative_se3`` to that gripper (the double-grasp task of §3.2.5.1, fig. 3.13
   steps 4-6; relative to the measured object once vision closes the loop, ch. 5);
3. ``posture`` following the planned configuration (regularisation, lowest priority) — except
   where a gripper task leaves the posture nothing to act on: an arm whose gripper is moved by
   no more joints than its se3 task has rows (a 6-DoF UR5 or UR10) has no null space below that
   task, so a posture one level down never acts, and through an elbow or wrist singularity the
   damped gripper task alone may take the other IK branch (the plan's branch is only in the
   posture). There the posture joins the gripper task's level (:func:`posture_joins_grippers`):
   stacked in one least-squares level, both follow the same planned motion, the posture rows keep
   the level full-rank through the singularity and the arm on the planned branch.

With ``gripper_admittance`` (opt-in, :func:`gripper_admittance_tasks`) group 2 also gets, for every
gripper with a joint, a ``gripper_admittance`` task while it holds a handle (closing, then holding
5 N: thesis 000 §3.2.4.3 and §3.2.5.1 "the transition where the robot closes its gripper ...
adds the position and admittance tasks", kept while the grasp holds) and at the step that
releases it (admittance down to 0 N, then position control to the open position); the posture
then leaves those joints alone.

The correspondence constraint kind -> task lives in one table, :data:`CONSTRAINT_TASKS`
(extend it there). Grasp / release events of a step are in the step (``created`` at its end,
``released`` at its start); the supervisor turns them into simulated grasp welds.

The specs are written to a readable, diffable YAML file and checked before execution
(:func:`check_specs`): unknown frames, rank loss of each priority level at the step's start
configuration, and a chain of steps that does not join up (a dead end of the FSM).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from marionette import robots
from marionette.control.spec import ControllerSpec, SpecError, TaskSpec
from marionette.execution.plan_steps import PlanRobotMap, Step
from marionette.execution.references import grip_ramp_s
from marionette.models import jaw
from marionette.models.semantics import Gripper, SemanticsError

SPECS_FORMAT = "marionette-controllers/1"

# End check (§3.2.5.2): ||e|| of each task kind below which a step has converged. A TALOS hand
# carrying the plank in MuJoCo sags ~1.3 cm under the position servos (measured): 2 cm on poses.
END_THRESHOLDS: dict[str, float] = {
    "se3": 0.02,
    "relative_se3": 0.02,
    "pbvs": 0.01,
    "position": 0.02,
    "com": 0.01,
    "posture": 0.1,
    "gaze": 0.05,
    # ||e|| = K_a |f - f*| / lambda while holding: 0.01 is 1 N with ADMITTANCE's K_a and GAINS'
    # lambda; in position control it is the lag behind the closing ramp [rad].
    "gripper_admittance": 0.01,
}
GAINS: dict[str, float] = {"balance": 10.0, "grasp": 5.0, "posture": 2.0, "gripper": 2.0}
# Gripper admittance parameters (thesis 000 §3.2.4.3: ~5 N, switch slightly below it); the others
# (gain K_a, lever arm, 5 Hz filter, ramp speed) are the controller's defaults
# (GripperAdmittanceOptions, cpp/include/marionette/sot/feature_gripper_admittance.h).
ADMITTANCE: dict[str, float] = {"force_target": 5.0, "force_threshold": 4.0}


@dataclass(frozen=True)
class GripperJoint:
    """The actuated joint of a gripper, its open / closed positions and the admittance
    parameters it sets over ADMITTANCE and the controller's defaults (robot.yaml)."""

    joint: str
    open_position: float
    closed_position: float
    parameters: dict[str, float] = field(default_factory=dict, hash=False)

    @property
    def closing_direction(self) -> float:
        """s of eq. 3.11-3.13: the sign of q̇ when closing."""
        return float(np.sign(self.closed_position - self.open_position))

    def closure(self, position: float) -> float:
        """How far along the stroke from open (0) to closed (1) the fingers are at ``position``."""
        return (position - self.open_position) / (self.closed_position - self.open_position)


@dataclass
class FactoryContext:
    """What the factory needs to know of the robot: its name, the controller's Pinocchio model,
    the link frame of each gripper (gripper name -> frame in that model) and the object of each
    handle (handle name -> object name)."""

    robot: str
    model: pin.Model
    gripper_frames: dict[str, str]
    handle_objects: dict[str, str]
    constraint_definitions: dict[str, dict[str, Any]] = field(default_factory=dict)
    graph_constraints: list[str] = field(default_factory=list)
    # Grippers that get gripper_admittance tasks (empty: none, the default).
    gripper_joints: dict[str, GripperJoint] = field(default_factory=dict)
    # Vision in the loop (a camera and `marionette perceive` run): the placement approach gets
    # pbvs tasks (VISUAL_WAYPOINTS); off, every gripper task follows its planned pose.
    visual_servoing: bool = False

    def local(self, name: str) -> str:
        """'talos/left_sole_link' -> 'left_sole_link' (the controller's model is unprefixed)."""
        prefix = f"{self.robot}/"
        return name[len(prefix) :] if name.startswith(prefix) else name


_REVOLUTE_AXES = {"JointModelRX": (1, 0, 0), "JointModelRY": (0, 1, 0), "JointModelRZ": (0, 0, 1)}


def hinge_lever_arm(model: pin.Model, g: Gripper) -> float | None:
    """d_axis-gripper of eq. 3.13 for a gripper whose jaw turns on a hinge: the distance from the
    joint's axis to the gripper frame's origin, where the jaws close on a handle (the same in
    every configuration: a rotation about the axis keeps distances to it). None when the joint
    is not a revolute joint of ``model`` (a slide has no lever arm: robot.yaml says so)."""
    if g.joint is None or not model.existJointName(g.joint):
        return None
    jid = model.getJointId(g.joint)
    joint = model.joints[jid]
    name = joint.shortname()
    if name in _REVOLUTE_AXES:
        axis_local = np.array(_REVOLUTE_AXES[name], dtype=float)
    elif name == "JointModelRevoluteUnaligned":
        axis_local = np.asarray(joint.extract().axis, dtype=float)
    else:
        return None
    if not model.existFrame(g.link):
        return None
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    X_WL = data.oMf[model.getFrameId(g.link)]
    p = X_WL.act(np.array(g.pose.xyz, dtype=float)) - data.oMi[jid].translation
    axis = data.oMi[jid].rotation @ axis_local
    return float(np.linalg.norm(p - axis * float(axis @ p)))


def gripper_joint(g: Gripper, model: pin.Model, robot: str) -> GripperJoint:
    """The actuated joint of ``g``, which must have one with its open and closed positions; its
    admittance parameters are robot.yaml's, and unless robot.yaml gives it the lever arm of
    eq. 3.13: by virtual work over the jaws' linkage when robot.yaml declares the jaws
    (:func:`squeeze_lever_arm`), else the hinge's radius (:func:`hinge_lever_arm`)."""
    if g.joint is None or g.open_position is None or g.closed_position is None:
        raise SemanticsError(
            f"gripper {g.name}: joint {g.joint} needs open_position and closed_position"
        )
    if g.open_position == g.closed_position:
        raise SemanticsError(
            f"gripper {g.name}: open_position and closed_position of {g.joint} are equal "
            f"({g.open_position}): the fingers would have no stroke"
        )
    parameters = dict(g.admittance)
    if "lever_arm" not in parameters:
        lever_arm = squeeze_lever_arm(robot, g.name)
        if lever_arm is None:
            lever_arm = hinge_lever_arm(model, g)
        if lever_arm is not None and lever_arm > 1e-3:
            parameters["lever_arm"] = lever_arm
    return GripperJoint(g.joint, g.open_position, g.closed_position, parameters)


@cache
def gripper_linkage(robot: str, gripper: str) -> jaw.Linkage | None:
    """The jaws of ``robot``'s ``gripper`` as its finger joint moves them
    (:class:`marionette.models.jaw.Linkage`, mimic joints included); None when robot.yaml
    declares no jaws for it or no joint with both positions."""
    from marionette.models.urdf import read_urdf

    g = robots.semantics(robot).gripper(gripper)
    jaws = robots.robot(robot).jaws.get(g.name)
    if jaws is None or g.joint is None or g.open_position is None or g.closed_position is None:
        return None
    urdf = read_urdf(robots.robot(robot).urdf)
    if g.joint not in urdf.joints:
        return None
    return jaw.Linkage(urdf, urdf.joints[g.joint], jaws, g.link, g.pose.matrix())


@cache
def squeeze_lever_arm(robot: str, gripper: str) -> float | None:
    """The motor torque per newton of squeeze of ``gripper`` at mid-stroke: eq. 3.13 by virtual
    work over its jaws' linkage (:func:`gripper_linkage`); None when it has none."""
    linkage = gripper_linkage(robot, gripper)
    if linkage is None:
        return None
    g = robots.semantics(robot).gripper(gripper)
    assert g.open_position is not None and g.closed_position is not None
    return linkage.squeeze_lever_arm((g.open_position + g.closed_position) / 2)


def context_from_plan(
    doc: dict[str, Any], robot: str, model: pin.Model, gripper_admittance: bool = False
) -> FactoryContext:
    """The factory's context for a plan; ``gripper_admittance`` adds admittance tasks for the
    plan's grippers that have a joint."""
    semantics = robots.semantics(robot).grippers
    links = {g.name: g.link for g in semantics}
    graph = doc["graph"]
    joints = {
        g.name: gripper_joint(g, model, robot)
        for g in semantics
        if gripper_admittance and g.joint is not None and g.name in doc["problem"]["grippers"]
    }
    return FactoryContext(
        robot=robot,
        model=model,
        gripper_frames={g: links.get(g, g.split("/", 1)[-1]) for g in doc["problem"]["grippers"]},
        handle_objects={h: d["object"] for h, d in doc["problem"]["handles"].items()},
        constraint_definitions=graph.get("constraint_definitions", {}),
        graph_constraints=list(graph.get("graph_constraints", [])),
        gripper_joints=joints,
    )


def _fixed_frame_task(name: str, definition: dict[str, Any], ctx: FactoryContext) -> list[TaskSpec]:
    """A relative transformation to the world (joint1 = universe) keeps a frame still: hold it
    where it is (the feet of §3.4: "CoM position, left and right feet positions")."""
    if definition.get("joint1") != "universe":
        return []  # a robot-robot relative constraint: none in the bundled problems
    frame = ctx.local(name.removesuffix(" fixed"))
    return [TaskSpec(task_name(frame), "se3", 0, frame=frame, gain=GAINS["balance"])]


def _com_task(name: str, definition: dict[str, Any], ctx: FactoryContext) -> list[TaskSpec]:
    """The CoM constraint of the planner is an inequality-like x-y hold (§3.2.5.1): the
    controller follows the planned CoM (all three components, as Agimus-HPP streams it)."""
    return [TaskSpec("com", "com", 0, gain=GAINS["balance"], streamed=True)]


def _no_task(name: str, definition: dict[str, Any], ctx: FactoryContext) -> list[TaskSpec]:
    return []  # locked joints: the posture task follows their (constant) planned value


# Constraint type (plan file, graph constraints) -> balance tasks. One place to extend.
CONSTRAINT_TASKS: dict[str, Callable[[str, dict[str, Any], FactoryContext], list[TaskSpec]]] = {
    "RelativeTransformation": _fixed_frame_task,
    "ComPosition": _com_task,
    "LockedJoint": _no_task,
}


def task_name(frame_or_gripper: str) -> str:
    """The name of the task that controls a frame or a gripper (``robot/gripper``)."""
    return frame_or_gripper.split("/")[-1].replace(".", "_").replace(" ", "_")


def balance_tasks(ctx: FactoryContext) -> list[TaskSpec]:
    tasks: list[TaskSpec] = []
    for name in ctx.graph_constraints:
        definition = ctx.constraint_definitions.get(name)
        if definition is None:
            raise SpecError(f"graph constraint {name!r} has no definition in the plan")
        rule = CONSTRAINT_TASKS.get(definition["type"])
        if rule is None:
            raise SpecError(
                f"graph constraint {name!r}: no task for constraint type "
                f"{definition['type']!r} (add it to CONSTRAINT_TASKS)"
            )
        tasks += rule(name, definition, ctx)
    return tasks


# Waypoint state a step leads to (suffix of the graph's state name) -> task kind of a gripper
# that holds its object all along the step: the carry to the pre-placement and the placement
# are servoed on the object pose the camera measures (thesis 000 §5.3.1: PBVS between
# pre-placement and placement; the reference is corrected by execution.visual_servo).
VISUAL_WAYPOINTS: dict[str, str] = {"preplace": "pbvs", "intersec": "pbvs"}
# ... and of a gripper approaching a handle of an object nobody holds: the approach to the
# pre-grasp (§5.3.1: "the grabbing of the plank"). The last centimetres to the grasp follow the
# plan shifted by the correction reached there ("then the reference trajectory computed by the
# motion planner is resumed, shifted"): servoed, they chased the plank the fingers pushed.
VISUAL_APPROACH_WAYPOINTS: dict[str, str] = {"pregrasp": "pbvs"}


def approached_handle(step: Step, gripper: str) -> str | None:
    """The handle ``gripper`` moves to in ``step`` when the step approaches a grasp (leads to its
    pre-grasp or to the grasp itself, the gripper holding nothing yet), None otherwise. The
    grasp itself is the waypoint ``intersec`` when the object also leaves its placement there, or
    the grasp's own state when it does not (a hand-over: the other gripper holds it)."""
    if gripper in step.grasps or gripper in step.grasps_from:
        return None
    if gripper in step.created:
        return step.grasps_to[gripper]
    if step.to_state.rsplit("_", 1)[-1] not in ("pregrasp", "intersec"):
        return None
    return step.grasps_to.get(gripper) or step.parent_grasps_to.get(gripper)


def visual_approach_kind(step: Step, gripper: str) -> str | None:
    """The task kind of ``gripper`` approaching a handle in ``step`` when vision corrects it
    (:data:`VISUAL_APPROACH_WAYPOINTS`), None otherwise."""
    if approached_handle(step, gripper) is None:
        return None
    return VISUAL_APPROACH_WAYPOINTS.get(step.to_state.rsplit("_", 1)[-1])


def visual_task_kind(step: Step) -> str | None:
    """The task kind of a gripper holding its object in ``step`` when vision corrects it
    (:data:`VISUAL_WAYPOINTS`), None otherwise. Lifting the object off its placement
    (intersec -> preplace) approaches no placement: not servoed."""
    to, frm = step.to_state.rsplit("_", 1)[-1], step.from_state.rsplit("_", 1)[-1]
    if to == "preplace" and frm == "intersec":
        return None
    return VISUAL_WAYPOINTS.get(to)


def step_holders(step: Step, ctx: FactoryContext) -> dict[str, str]:
    """Object -> a gripper that holds it all along ``step``."""
    return {ctx.handle_objects.get(h, h): g for g, h in step.grasps.items()}


def grasp_tasks(step: Step, ctx: FactoryContext, priority: int) -> list[TaskSpec]:
    """Group 2: a streamed pose task per active gripper; a gripper on an object that another
    gripper already holds is placed relative to that gripper."""
    tasks: list[TaskSpec] = []
    holder_of: dict[str, str] = {}  # object -> gripper with an absolute task
    for gripper in step.active_grippers:
        handle = (
            step.grasps.get(gripper)
            or step.parent_grasps_to.get(gripper)
            or step.parent_grasps_from.get(gripper)
            or step.grasps_from.get(gripper)
            or step.grasps_to.get(gripper)
        )
        assert handle is not None  # an active gripper is a key of one of these grasp maps
        obj = ctx.handle_objects.get(handle, handle)
        frame = ctx.gripper_frames[gripper]
        name = task_name(gripper)
        if (
            ctx.visual_servoing
            and gripper in step.grasps
            and (kind := visual_task_kind(step)) is not None
        ):
            tasks.append(
                TaskSpec(
                    name,
                    kind,
                    priority,
                    frame=frame,
                    gain=GAINS["grasp"],
                    streamed=True,
                )
            )
            holder_of[obj] = gripper
        elif (
            ctx.visual_servoing
            and obj not in holder_of
            and obj not in step_holders(step, ctx)
            and (kind := visual_approach_kind(step, gripper)) is not None
        ):
            tasks.append(
                TaskSpec(
                    name,
                    kind,
                    priority,
                    frame=frame,
                    gain=GAINS["grasp"],
                    streamed=True,
                )
            )
        elif obj in holder_of:
            other = ctx.gripper_frames[holder_of[obj]]
            tasks.append(
                TaskSpec(
                    name,
                    "relative_se3",
                    priority,
                    frame=frame,
                    frame_b=other,
                    gain=GAINS["grasp"],
                    streamed=True,
                )
            )
        else:
            tasks.append(
                TaskSpec(name, "se3", priority, frame=frame, gain=GAINS["grasp"], streamed=True)
            )
            holder_of[obj] = gripper
    return tasks


def gripper_admittance_tasks(
    step: Step, ctx: FactoryContext, priority: int, previous: Step | None = None
) -> list[TaskSpec]:
    """A ``gripper_admittance`` task per gripper of ``ctx.gripper_joints`` that holds a handle all
    along the step (close on it, then hold 5 N) or releases one at the step's start (admittance to
    0 N, then open). The grasp's own step (``created`` at its end) has none: the gripper closes
    once the hand is on the handle, in the next step (§3.2.5.1). A hand-over — this step
    releases an object whose grasp by another gripper ``previous`` created, so that gripper
    closes in this step — keeps the releasing grip for the receiving gripper's whole closing
    ramp first (``release_after``): both ramps at once dropped the plank between the hands."""
    tasks: list[TaskSpec] = []
    for gripper, g in sorted(ctx.gripper_joints.items()):
        release = gripper in step.released
        if not release and gripper not in step.grasps:
            continue
        target = g.open_position if release else g.closed_position
        parameters = dict(
            ADMITTANCE,
            **g.parameters,
            closing_direction=g.closing_direction,
            release=float(release),
        )
        if release and (wait := handover_wait_s(step, gripper, ctx, previous)) > 0:
            parameters["release_after"] = wait
        tasks.append(
            TaskSpec(
                f"{task_name(gripper)}_admittance",
                "gripper_admittance",
                priority,
                gain=GAINS["gripper"],
                reference=[target],
                joints=[g.joint],
                parameters=parameters,
            )
        )
    return tasks


def handover_wait_s(
    step: Step, releasing: str, ctx: FactoryContext, previous: Step | None
) -> float:
    """How long [s] gripper ``releasing`` keeps its grip at ``step``'s start: the closing ramp
    (:func:`references.grip_ramp_s`, whole stroke) of each gripper that ``previous`` made grasp
    the object it releases; 0 when none did (not a hand-over, or no admittance drives them)."""
    if previous is None:
        return 0.0
    obj = ctx.handle_objects.get(step.released[releasing], step.released[releasing])
    wait = 0.0
    for receiver, handle in previous.created.items():
        g = ctx.gripper_joints.get(receiver)
        if receiver == releasing or g is None or ctx.handle_objects.get(handle, handle) != obj:
            continue
        stroke = abs(g.closed_position - g.open_position)
        wait = max(wait, grip_ramp_s(stroke, {**ADMITTANCE, **g.parameters}))
    return wait


def _posture_task(ctx: FactoryContext, admittance: list[TaskSpec]) -> TaskSpec:
    """The posture over every 1-DoF joint but those an admittance task drives (it would pull the
    gripper back to the planned opening and never converge)."""
    driven = {j for t in admittance for j in t.joints}
    joints = (
        []
        if not driven
        else [
            ctx.model.names[j]
            for j in range(1, ctx.model.njoints)
            if ctx.model.joints[j].nv == 1 and ctx.model.names[j] not in driven
        ]
    )
    return TaskSpec("posture", "posture", 0, gain=GAINS["posture"], streamed=True, joints=joints)


def chain_dof(model: pin.Model, frame: str) -> int:
    """The 1-DoF joints that move ``frame`` (its parent joint's support, base excluded)."""
    joint = model.frames[model.getFrameId(frame)].parentJoint
    return sum(1 for j in model.supports[joint] if j > 0 and model.joints[j].nv == 1)


def task_rows(task: TaskSpec) -> int:
    full = {"se3": 6, "pbvs": 6, "relative_se3": 6, "position": 3, "com": 3}.get(task.kind, 0)
    return sum(bool(m) for m in task.mask) if len(task.mask) else full


def posture_joins_grippers(grasps: list[TaskSpec], ctx: FactoryContext) -> bool:
    """True when a gripper follows its planned pose (``se3``: no vision correction to give way
    to) with no more joints than the task has rows: no redundancy is left for a posture below it
    (module doc, group 3)."""
    return any(t.kind == "se3" and chain_dof(ctx.model, t.frame) <= task_rows(t) for t in grasps)


def build_spec(
    step: Step,
    ctx: FactoryContext,
    controller_id: int | None = None,
    previous: Step | None = None,
) -> ControllerSpec:
    """The controller of one step (levels numbered from 0 without gaps); ``previous``, the step
    executed before it, tells a hand-over (:func:`gripper_admittance_tasks`)."""
    admittance = gripper_admittance_tasks(step, ctx, 0, previous)
    grasps = grasp_tasks(step, ctx, 0)
    posture = _posture_task(ctx, admittance)
    if posture_joins_grippers(grasps, ctx):
        levels = [balance_tasks(ctx), grasps + admittance + [posture]]
    else:
        levels = [balance_tasks(ctx), grasps + admittance, [posture]]
    tasks: list[TaskSpec] = []
    for priority, level in enumerate(lv for lv in levels if lv):
        for t in level:
            t.priority = priority
            tasks.append(t)
    spec = ControllerSpec(
        step.index + 1 if controller_id is None else controller_id,
        f"step{step.index} {step.transition}",
        tasks,
        max_switch_velocity_jump=0.1,
        reference_timeout=0.2,
    )
    spec.check()
    return spec


def build_specs(steps: list[Step], ctx: FactoryContext) -> list[ControllerSpec]:
    return [build_spec(s, ctx, previous=p) for s, p in zip(steps, [None, *steps[:-1]])]


# ---- spec file ------------------------------------------------------------------------------


def specs_document(
    steps: list[Step], specs: list[ControllerSpec], plan_name: str
) -> dict[str, Any]:
    return {
        "format": SPECS_FORMAT,
        "plan": plan_name,
        "end_thresholds": END_THRESHOLDS,
        "steps": [
            {
                "index": s.index,
                "transition": s.transition,
                "parent_transition": s.parent_transition,
                "kind": s.kind,
                "release_at_start": s.released,
                "grasp_at_end": s.created,
                "plan_paths": s.path_indices,
                "controller": spec.to_dict(),
            }
            for s, spec in zip(steps, specs)
        ],
    }


def write_specs(
    path: str | Path, steps: list[Step], specs: list[ControllerSpec], plan_name: str
) -> Path:
    """The readable, diffable controller file (YAML, one entry per FSM state)."""
    path = Path(path)
    path.write_text(
        yaml.safe_dump(specs_document(steps, specs, plan_name), sort_keys=False, width=100)
    )
    return path


def read_specs(path: str | Path) -> list[ControllerSpec]:
    doc = yaml.safe_load(Path(path).read_text())
    if not isinstance(doc, dict) or doc.get("format") != SPECS_FORMAT:
        raise SpecError(f"{path}: not a {SPECS_FORMAT} file")
    return [ControllerSpec.from_dict(s["controller"]) for s in doc["steps"]]


# ---- checks before execution ----------------------------------------------------------------


def task_jacobian(
    model: pin.Model, data: pin.Data, task: TaskSpec, q: np.ndarray, posture_rows: bool = False
) -> np.ndarray | None:
    """The task's Jacobian (rows x nv) at q (kinematics already computed at q). The posture's
    (selection rows of its joints) only with ``posture_rows``: alone on its level it is a
    regularisation, which never loses rank; None then, and for kinds without a Jacobian here."""
    if task.kind == "posture":
        if not posture_rows:
            return None
        names = list(task.joints) or [
            model.names[j] for j in range(1, model.njoints) if model.joints[j].nv == 1
        ]
        J = np.zeros((len(names), model.nv))
        for i, name in enumerate(names):
            J[i, model.joints[model.getJointId(name)].idx_v] = 1.0
        return J
    if task.kind in ("se3", "pbvs"):
        J = pin.getFrameJacobian(model, data, model.getFrameId(task.frame), pin.LOCAL)
    elif task.kind == "position":
        J = pin.getFrameJacobian(
            model, data, model.getFrameId(task.frame), pin.LOCAL_WORLD_ALIGNED
        )[:3]
    elif task.kind == "relative_se3":
        fa, fb = model.getFrameId(task.frame), model.getFrameId(task.frame_b)
        X_AB = data.oMf[fa].actInv(data.oMf[fb])
        J = pin.getFrameJacobian(
            model, data, fa, pin.LOCAL
        ) - X_AB.toActionMatrix() @ pin.getFrameJacobian(model, data, fb, pin.LOCAL)
    elif task.kind == "com":
        J = pin.jacobianCenterOfMass(model, data, q)
    else:
        return None
    if len(task.mask):
        J = J[[i for i, m in enumerate(task.mask) if m]]
    return J


def task_error(
    model: pin.Model, data: pin.Data, task: TaskSpec, q: np.ndarray, data_ref: pin.Data
) -> np.ndarray | None:
    """The task's error at q (frames and centre of mass already computed in ``data``) against the
    same task at the configuration whose kinematics ``data_ref`` holds, in the coordinates of
    :func:`task_jacobian` (to first order e(q + dq) = e(q) + J dq); None where it has none."""
    if task.kind in ("se3", "pbvs"):
        f = model.getFrameId(task.frame)
        e = pin.log6(data_ref.oMf[f].actInv(data.oMf[f])).vector
    elif task.kind == "position":
        f = model.getFrameId(task.frame)
        e = data.oMf[f].translation - data_ref.oMf[f].translation
    elif task.kind == "relative_se3":
        fa, fb = model.getFrameId(task.frame), model.getFrameId(task.frame_b)
        # J is the velocity of A relative to B, in A: the derivative of X_BA = X_B^-1 X_A
        X_BA, X_BA_ref = (d.oMf[fb].actInv(d.oMf[fa]) for d in (data, data_ref))
        e = pin.log6(X_BA_ref.actInv(X_BA)).vector
    elif task.kind == "com":  # both centres of mass computed (pin.centerOfMass)
        e = data.com[0] - data_ref.com[0]
    else:
        return None
    if len(task.mask):
        e = e[[i for i, m in enumerate(task.mask) if m]]
    return e


@dataclass(frozen=True)
class LevelConditioning:
    """One priority level of a controller at a configuration, the levels above projected out:
    its tasks, the rows of its tasks (a stacked posture left out), the rank those rows get, the
    rank they can get (``attainable``: each task's rows, or the DoF left to it that its rows
    move when those are fewer — a 5-DoF arm's gripper pose), and the smallest singular value
    the level needs — of its task rows, or, with a posture stacked in it, of the whole level
    over the DoF left to it that its rows move (0 when it needs more DoF than are left)."""

    priority: int
    tasks: tuple[str, ...]
    rows: int
    rank: int
    sigma_min: float
    attainable: int


def _svd_values(J: np.ndarray) -> np.ndarray:
    return np.linalg.svd(J, compute_uv=False) if J.size else np.zeros(0)


def level_conditioning(
    model: pin.Model, data: pin.Data, spec: ControllerSpec, q: np.ndarray, tol: float = 1e-6
) -> list[LevelConditioning]:
    """Every level of ``spec`` with a Jacobian at ``q`` (nq), the levels above projected out (the
    strict hierarchy the controller solves); a posture alone on its level is left out (a
    regularisation)."""
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    pin.centerOfMass(model, data, q)
    out: list[LevelConditioning] = []
    N = np.eye(model.nv)  # null-space basis of the levels above
    for level in sorted({t.priority for t in spec.tasks}):
        tasks = [t for t in spec.tasks if t.priority == level]
        Js = [J for J in (task_jacobian(model, data, t, q) for t in tasks) if J is not None]
        stacked = [
            P
            for P in (
                task_jacobian(model, data, t, q, posture_rows=True)
                for t in tasks
                if t.kind == "posture" and Js
            )
            if P is not None
        ]
        if not Js:
            continue
        J = np.vstack(Js) @ N
        s = _svd_values(J)
        rank = int(np.sum(s > tol * max(1.0, s[0]))) if len(s) else 0
        attainable = sum(  # a task on fewer DoF than its rows can have no more rank than them
            min(len(Ji), int(np.sum(_svd_values(N[np.any(Ji != 0.0, axis=0)]) > tol))) for Ji in Js
        )
        needed = J.shape[0]
        if stacked:  # the level is the least squares of its tasks and the posture
            raw = np.vstack([*Js, *stacked])
            J = np.vstack([J, *(P @ N for P in stacked)])
            s = _svd_values(J)
            # over the DoF left to it that its rows move (a joint no row of the level touches,
            # e.g. a finger another kind of task drives, is no lost rank)
            touched = np.any(raw != 0.0, axis=0)
            free = _svd_values(N[touched])
            needed = min(needed, int(np.sum(free > tol)))
        sigma = float(s[needed - 1]) if 0 < needed <= len(s) else 0.0
        rows = sum(len(Ji) for Ji in Js)
        out.append(
            LevelConditioning(level, tuple(t.name for t in tasks), rows, rank, sigma, attainable)
        )
        if N.shape[1]:
            _, sv, Vt = np.linalg.svd(J)
            used = int(np.sum(sv > tol * max(1.0, sv[0]))) if len(sv) else 0
            N = N @ Vt[used:].T if used < Vt.shape[0] else np.zeros((model.nv, 0))
    return out


def check_specs(
    steps: list[Step],
    specs: list[ControllerSpec],
    ctx: FactoryContext,
    robot_map: PlanRobotMap,
    tol: float = 1e-6,
) -> list[str]:
    """Problems that would make execution fail, as messages (empty list: good to go)."""
    problems: list[str] = []
    model = ctx.model
    data = model.createData()
    for step, spec in zip(steps, specs):
        where = f"step {step.index} ({step.transition})"
        for t in spec.tasks:
            for f in (t.frame, t.frame_b):
                if f and not model.existFrame(f):
                    problems.append(f"{where}: task {t.name!r}: unknown frame {f!r}")
        if any(p.startswith(where) for p in problems):
            continue
        q = robot_map.robot_q(step.q[0])
        for level in level_conditioning(model, data, spec, q, tol):
            if level.rank < level.attainable:
                problems.append(
                    f"{where}: priority {level.priority} ({', '.join(level.tasks)}) loses rank "
                    f"at the step's start configuration: {level.rank} < {level.attainable}"
                )
    for a, b in zip(steps, steps[1:]):
        gap = np.linalg.norm(
            pin.difference(model, robot_map.robot_q(a.q[-1]), robot_map.robot_q(b.q[0]))
        )
        if gap > 1e-3:  # [rad] a smaller gap is absorbed by the tracking of the first samples
            problems.append(
                f"step {a.index} ends {gap:.3g} rad away from where step {b.index} "
                "starts: the FSM has no way from one to the other"
            )
    return problems
