"""Task references of a step sampled at the controller rate (thesis 000 §3.3.6, Agimus-HPP: "the
sampling of the path before the transmission to the controllers ... calls Pinocchio to add the
positions of the CoM and important parts of the robot, such as the hands").

Time law: the step's robot configurations are a polyline in q parametrised by arc length s
(|Δq| in the velocity space of the robot's model). It is run along a quintic
s(t) = L (10 u³ − 15 u⁴ + 6 u⁵), u = t/T, at rest at both ends (so the controller switches
between steps at rest: the start check of §3.2.5.2 sees no jump), with the duration T chosen so
that no joint exceeds ``max_joint_velocity``: the quintic's peak speed is 15/8 L/T, and a joint
moves at |dq_j/ds| ṡ.

References, for a task of a ControllerSpec, sample by sample (rows):
  se3            X_WF of the task frame: (x y z qw qx qy qz), derivative (v_W, ω_W) (6)
  relative_se3   X_BA (frame in frame_b): 7 values, derivative (v, ω) in B axes (6)
  com            c_W (3), derivative ċ_W (3)
  posture        q (nq), derivative v (nv)
Derivatives are central differences of the sampled values (one-sided at the ends, where the
quintic is at rest).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from marionette.control.spec import ControllerSpec, SpecError, TaskSpec
from marionette.execution.plan_steps import PlanRobotMap, Step


@dataclass
class StepTrajectory:
    """The time-sampled motion of one step: ``t`` (N,) [s] from the step's start, ``q`` (N x nq)
    robot configurations, ``q_plan`` (N x nq_plan) full plan configurations (objects too)."""

    dt: float
    duration: float
    t: np.ndarray
    q: np.ndarray
    q_plan: np.ndarray
    references: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    # How much slower than its time law (and its declared slowdown) the step was re-timed for its
    # rewritten references to respect the joints' bounds (1: not re-timed), and the joint that
    # asked for it ("" when none).
    retimed: float = 1.0
    retimed_for: str = ""
    # [rad] how far a gaze rewrite leaned the torso for the camera to see the servoed object
    lean: float = 0.0

    @property
    def num_samples(self) -> int:
        return len(self.t)


def minimum_jerk(
    p0: np.ndarray, p1: np.ndarray, duration_s: float, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Samples (N x d) of p(t) = p0 + (p1 - p0) s(t/T), s = 10 u^3 - 15 u^4 + 6 u^5 (the time law
    of :func:`sample_step`, at rest at both ends), and their time derivatives (Flash & Hogan),
    from t = 0 to T inclusive, for points p0, p1 of any dimension d."""
    u = np.linspace(0.0, 1.0, round(duration_s / dt_s) + 1)[:, None]
    s = 10 * u**3 - 15 * u**4 + 6 * u**5
    ds = (30 * u**2 - 60 * u**3 + 30 * u**4) / duration_s
    return p0 + s * (p1 - p0), ds * (p1 - p0)


def arc_length(model: pin.Model, q: np.ndarray) -> np.ndarray:
    """Cumulative |Δq| (velocity-space norm) along the rows of q (k x nq) -> (k,)."""
    seg = [float(np.linalg.norm(pin.difference(model, a, b))) for a, b in zip(q, q[1:])]
    return np.concatenate([[0.0], np.cumsum(seg)])


# Streamed velocities keep this fraction of a joint's own limit (the URDF's, which the
# controller's safety filter clamps at): the rest is headroom for the feedback that catches up a
# lag while the feed-forward runs.
LIMIT_FRACTION = 0.8


def velocity_limits(
    model: pin.Model, max_joint_velocity: float, fraction: float = LIMIT_FRACTION
) -> np.ndarray:
    """(nv,) the velocity bound of every velocity component of ``model``: ``max_joint_velocity``
    (the scenario's time law), lowered to ``fraction`` of a 1-DoF joint's velocity limit where
    that is smaller (TALOS's head: 1 rad/s)."""
    if max_joint_velocity <= 0.0:
        raise ValueError(f"max_joint_velocity must be > 0, got {max_joint_velocity}")
    limits = np.full(model.nv, float(max_joint_velocity))
    for j in range(1, model.njoints):
        joint = model.joints[j]
        if joint.nv != 1:
            continue
        own = float(model.velocityLimit[joint.idx_v])
        if np.isfinite(own) and own > 0.0:
            limits[joint.idx_v] = min(limits[joint.idx_v], fraction * own)
    return limits


def _bounds(model: pin.Model, max_joint_velocity: float | np.ndarray) -> np.ndarray:
    limits = np.broadcast_to(np.asarray(max_joint_velocity, dtype=float), (model.nv,))
    if not np.all(limits > 0.0):
        raise ValueError(f"joint velocity bounds must be > 0, got {max_joint_velocity}")
    return limits


def step_duration(
    model: pin.Model,
    q: np.ndarray,
    max_joint_velocity: float | np.ndarray,
    min_duration: float = 0.5,
) -> float:
    """Duration [s] of the quintic time law along the polyline q (k x nq) such that no joint
    (velocity-space component j) exceeds ``max_joint_velocity`` (a scalar, or (nv,) per
    component: :func:`velocity_limits`)."""
    limits = _bounds(model, max_joint_velocity)
    s = arc_length(model, q)
    length = s[-1]
    if length <= 0.0:
        return min_duration
    dq = np.array([pin.difference(model, a, b) for a, b in zip(q, q[1:])])  # (k-1) x nv
    ds = np.diff(s)
    ok = ds > 0
    slope = np.max(np.abs(dq[ok]) / ds[ok, None] / limits)  # max_j |dq_j/ds| / bound_j
    sdot_max = 1.0 / max(slope, 1e-9)
    return max(min_duration, 15.0 / 8.0 * length / sdot_max)


def sample_step(
    step: Step,
    robot_map: PlanRobotMap,
    dt: float = 1e-3,
    max_joint_velocity: float | np.ndarray = 0.5,
    min_duration: float = 0.5,
) -> StepTrajectory:
    """The step's configurations every ``dt`` along its time law (both ends included);
    ``max_joint_velocity`` as in :func:`step_duration`."""
    model = robot_map.model
    q_robot = robot_map.robot_q(step.q)
    s = arc_length(model, q_robot)
    T = step_duration(model, q_robot, max_joint_velocity, min_duration)
    n = max(1, math.ceil(T / dt))
    T = n * dt
    t = np.arange(n + 1) * dt
    u = t / T
    sigma = s[-1] * (10 * u**3 - 15 * u**4 + 6 * u**5)
    idx = np.clip(np.searchsorted(s, sigma, side="right") - 1, 0, len(s) - 2)
    ds = s[idx + 1] - s[idx]
    frac = np.where(ds > 0, (sigma - s[idx]) / np.where(ds > 0, ds, 1.0), 0.0)
    frac = np.clip(frac, 0.0, 1.0)
    q = np.empty((n + 1, model.nq))
    for k in range(n + 1):
        q[k] = pin.interpolate(model, q_robot[idx[k]], q_robot[idx[k] + 1], frac[k])
    q[0], q[-1] = q_robot[0], q_robot[-1]
    # The whole plan configuration (objects) linearly between samples, for reports only.
    q_plan = step.q[idx] + (step.q[idx + 1] - step.q[idx]) * frac[:, None]
    return StepTrajectory(dt, T, t, q, q_plan)


def dwell(traj: StepTrajectory, seconds: float) -> None:
    """Holds the step's last sample ``seconds`` longer (references at rest): the robot waits at
    the waypoint, e.g. while vision corrects the pre-grasp before the grasp (§5.3.1: "when the
    robot reaches the waypoint, the visual servoing task is activated ... then the reference
    trajectory computed by the motion planner is resumed")."""
    n = round(seconds / traj.dt)
    if n <= 0:
        return
    traj.t = np.concatenate([traj.t, traj.t[-1] + traj.dt * np.arange(1, n + 1)])
    traj.duration = float(traj.t[-1])
    traj.q = np.vstack([traj.q, np.repeat(traj.q[-1:], n, axis=0)])
    traj.q_plan = np.vstack([traj.q_plan, np.repeat(traj.q_plan[-1:], n, axis=0)])
    for name, (values, derivatives) in traj.references.items():
        traj.references[name] = (
            np.vstack([values, np.repeat(values[-1:], n, axis=0)]),
            np.vstack([derivatives, np.zeros((n, derivatives.shape[1]))]),
        )


def lead_in(traj: StepTrajectory, seconds: float) -> None:
    """Holds the step's first sample ``seconds`` before its motion (references at rest): the
    robot waits where the previous step left it, e.g. while its gripper closes on the handle."""
    n = round(seconds / traj.dt)
    if n <= 0:
        return
    traj.t = np.concatenate([traj.dt * np.arange(n), traj.t + n * traj.dt])
    traj.duration = float(traj.t[-1])
    traj.q = np.vstack([np.repeat(traj.q[:1], n, axis=0), traj.q])
    traj.q_plan = np.vstack([np.repeat(traj.q_plan[:1], n, axis=0), traj.q_plan])
    for name, (values, derivatives) in traj.references.items():
        traj.references[name] = (
            np.vstack([np.repeat(values[:1], n, axis=0), values]),
            np.vstack([np.zeros((n, derivatives.shape[1])), derivatives]),
        )


# [s] after a gripper's ramp, for its grip force to settle: the estimate's 5 Hz filter and the
# admittance loop (10/s) each take ~0.1 s per time constant.
GRIP_SETTLE_S = 0.5


def grip_change_s(step: Step, previous: Step | None, spec: ControllerSpec, robot: str) -> float:
    """How long the arm waits at ``step``'s start while a gripper changes its grip, as §3.2.5.1
    orders it: a gripper closes on the handle the previous step reached before the robot moves
    the object, and opens before the robot recedes from one it releases. The time of the
    ``gripper_admittance`` task's ramp over the gripper's whole stroke (its speed and
    acceleration), then :data:`GRIP_SETTLE_S`; 0 when no grip changes or no admittance task
    drives the gripper (a welded grasp holds at once). A gripper handing its object over waits
    its task's ``release_after`` first (:func:`factory.gripper_admittance_tasks`)."""
    from marionette import robots

    changing = set(step.released) | set(previous.created if previous is not None else {})
    seconds = 0.0
    for name in changing:
        gripper = robots.semantics(robot).gripper(name)
        task = next(
            (
                t
                for t in spec.tasks
                if t.kind == "gripper_admittance" and list(t.joints) == [gripper.joint]
            ),
            None,
        )
        if task is None or gripper.open_position is None or gripper.closed_position is None:
            continue
        stroke = abs(gripper.closed_position - gripper.open_position)
        # A releasing gripper of a hand-over keeps its grip release_after s before its ramp.
        wait = float(task.parameters.get("release_after", 0.0))
        seconds = max(seconds, wait + grip_ramp_s(stroke, task.parameters))
    return seconds


def grip_ramp_s(stroke: float, parameters: dict[str, float]) -> float:
    """How long [s] a ``gripper_admittance`` task with ``parameters`` (over the controller's
    defaults) takes to ramp over ``stroke`` [rad or m] — its speed, its acceleration at both
    ends — and for the grip force to settle after it (:data:`GRIP_SETTLE_S`)."""
    from marionette import _core

    p = {**_core.gripper_admittance_defaults(), **parameters}
    return stroke / p["speed"] + p["speed"] / p["acceleration"] + GRIP_SETTLE_S


def _central(values: np.ndarray, dt: float) -> np.ndarray:
    d = np.zeros_like(values)
    if len(values) > 2:
        d[1:-1] = (values[2:] - values[:-2]) / (2 * dt)
    return d


def _pose_rows(poses: list[pin.SE3]) -> np.ndarray:
    out = np.empty((len(poses), 7))
    for k, X in enumerate(poses):
        quat = pin.Quaternion(X.rotation)
        out[k] = [*X.translation, quat.w, quat.x, quat.y, quat.z]
    return out


def _pose_derivatives(poses: list[pin.SE3], dt: float) -> np.ndarray:
    """(v, ω) in the poses' reference axes, central differences (zero at the ends)."""
    out = np.zeros((len(poses), 6))
    for k in range(1, len(poses) - 1):
        a, b = poses[k - 1], poses[k + 1]
        out[k, :3] = (b.translation - a.translation) / (2 * dt)
        out[k, 3:] = poses[k].rotation @ pin.log3(a.rotation.T @ b.rotation) / (2 * dt)
    return out


def compute_references(traj: StepTrajectory, spec: ControllerSpec, model: pin.Model) -> None:
    """Fills ``traj.references[task] = (values, derivatives)`` for every streamed task."""
    data = model.createData()
    streamed = [t for t in spec.tasks if t.streamed]
    frames = {f for t in streamed for f in (t.frame, t.frame_b) if f}
    for f in frames:
        if not model.existFrame(f):
            raise SpecError(f"controller {spec.name!r}: unknown frame {f!r}")
    fid = {f: model.getFrameId(f) for f in frames}
    need_com = any(t.kind == "com" for t in streamed)
    poses: dict[str, list[pin.SE3]] = {f: [] for f in frames}
    com = np.empty((traj.num_samples, 3))
    for k, q in enumerate(traj.q):
        pin.framesForwardKinematics(model, data, q)
        for f in frames:
            poses[f].append(pin.SE3(data.oMf[fid[f]]))
        if need_com:
            com[k] = pin.centerOfMass(model, data, q, False)
    for task in streamed:
        traj.references[task.name] = _task_reference(task, traj, model, poses, com)


def _task_reference(
    task: TaskSpec,
    traj: StepTrajectory,
    model: pin.Model,
    poses: dict[str, list[pin.SE3]],
    com: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    if task.kind in ("se3", "pbvs"):
        X = poses[task.frame]
        return _pose_rows(X), _pose_derivatives(X, traj.dt)
    if task.kind == "relative_se3":
        X = [b.actInv(a) for a, b in zip(poses[task.frame], poses[task.frame_b])]
        return _pose_rows(X), _pose_derivatives(X, traj.dt)
    if task.kind == "position":
        p = np.array([X.translation for X in poses[task.frame]])
        return p, _central(p, traj.dt)
    if task.kind == "com":
        return com.copy(), _central(com, traj.dt)
    if task.kind == "posture":
        v = np.zeros((traj.num_samples, model.nv))
        for k in range(1, traj.num_samples - 1):
            v[k] = pin.difference(model, traj.q[k - 1], traj.q[k + 1]) / (2 * traj.dt)
        return traj.q.copy(), v
    raise SpecError(f"task {task.name!r}: no planned reference for a {task.kind!r} task")


# ---- feasibility: re-timing a rewritten step -----------------------------------------------


def _quaternion_rows_to_matrices(quat_xyzw: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of unit quaternions (N, 4) in Pinocchio's (x y z w) order."""
    x, y, z, w = (quat_xyzw / np.linalg.norm(quat_xyzw, axis=1, keepdims=True)).T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def configuration_velocities(model: pin.Model, q: np.ndarray, dt: float) -> np.ndarray:
    """((N-1) x nv) forward differences of the configurations q (N x nq) sampled every ``dt``:
    1-DoF joints by subtraction; a free flyer's linear velocity in its own frame (R₀ᵀ Δp) and
    angular velocity from the rotation between samples (log₃, vectorised: the order of
    ``pin.difference`` between samples 1 ms apart); other joints by ``pin.difference``."""
    v = np.empty((max(len(q) - 1, 0), model.nv))
    for j in range(1, model.njoints):
        joint = model.joints[j]
        iq, iv = joint.idx_q, joint.idx_v
        if joint.nq == joint.nv == 1:
            v[:, iv] = np.diff(q[:, iq]) / dt
        elif joint.shortname() == "JointModelFreeFlyer" and len(q) > 1:
            R = _quaternion_rows_to_matrices(q[:, iq + 3 : iq + 7])
            dp = np.diff(q[:, iq : iq + 3], axis=0)
            v[:, iv : iv + 3] = np.einsum("kji,kj->ki", R[:-1], dp) / dt
            dR = np.einsum("kji,kjl->kil", R[:-1], R[1:])  # R0^T R1
            cos = np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0)
            angle = np.arccos(cos)
            axis = np.stack(
                [dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0], dR[:, 1, 0] - dR[:, 0, 1]],
                -1,
            )
            scale = np.where(angle > 1e-9, angle / (2 * np.sin(np.maximum(angle, 1e-9))), 0.5)
            v[:, iv + 3 : iv + 6] = axis * scale[:, None] / dt
        else:
            sl = slice(iv, iv + joint.nv)
            for k in range(len(q) - 1):
                v[k, sl] = pin.difference(model, q[k], q[k + 1])[sl] / dt
    return v


def speed_ratio(model: pin.Model, traj: StepTrajectory, limits: np.ndarray) -> tuple[float, int]:
    """max_j |v_j| / bound_j over the step and the velocity component j where it is reached:
    v the differences of the streamed posture reference (the configuration the controller is
    asked to follow) and its feed-forward, and of ``traj.q`` (what the task references were
    computed from). ≤ 1: every streamed reference respects ``limits`` (nv,)."""
    rows = [configuration_velocities(model, traj.q, traj.dt)]
    if "posture" in traj.references:
        values, derivatives = traj.references["posture"]
        rows += [configuration_velocities(model, values, traj.dt), derivatives]
    v = np.abs(np.vstack(rows)) / limits
    if not v.size:
        return 0.0, 0
    j = int(np.argmax(v.max(axis=0)))
    return float(v[:, j].max()), j


# A rewrite of a sampled step's references: (step, its trajectory, whether it is the first step
# run), in place, as a function of the path and of the normalised time t / duration only (so
# that the same rewrite of a re-timed step is as much slower as the step).
Rewrite = Callable[[Step, StepTrajectory, bool], None]


@dataclass(frozen=True)
class StepTiming:
    """How one step is played beyond its time law: ``lead_in_s`` at rest on its first sample (a
    gripper changes its grip), ``slowdown`` times slower (a servoed step waits for more camera
    frames), then ``dwell_s`` at rest on its last sample."""

    slowdown: float = 1.0
    dwell_s: float = 0.0
    lead_in_s: float = 0.0

    def __post_init__(self) -> None:
        if self.slowdown < 1.0 or self.dwell_s < 0.0 or self.lead_in_s < 0.0:
            raise ValueError(f"need slowdown >= 1, dwell_s >= 0 and lead_in_s >= 0, got {self}")


def velocity_component_name(model: pin.Model, j: int) -> str:
    """The joint of velocity component ``j`` (``root_joint[3]`` inside a multi-DoF joint)."""
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.idx_v <= j < joint.idx_v + joint.nv:
            return model.names[jid] + (f"[{j - joint.idx_v}]" if joint.nv > 1 else "")
    return f"v[{j}]"


def shaped_trajectory(
    step: Step,
    spec: ControllerSpec,
    robot_map: PlanRobotMap,
    limits: np.ndarray,
    dt: float = 1e-3,
    min_duration: float = 0.5,
    timing: StepTiming = StepTiming(),
    rewrites: Sequence[Rewrite] = (),
    first: bool = False,
    max_attempts: int = 6,
    max_duration_s: float = 600.0,
) -> StepTrajectory:
    """The step sampled along its time law (bounded by ``limits`` (nv,), ``timing.slowdown``
    slower), its references computed for ``spec``, rewritten by ``rewrites``, re-timed until
    every streamed reference respects ``limits`` (module doc), held ``timing.lead_in_s`` before
    and ``timing.dwell_s`` after.
    ValueError when no re-timing brings it within: after ``max_attempts``, when the step would
    last more than ``max_duration_s``, or at once when slowing it did not reduce the excess (a
    rewrite whose reference jumps asks the same velocity at any pace: re-timing it grew the
    samples geometrically, 21 GB before the kernel killed the demo)."""
    model = robot_map.model
    stretch = timing.slowdown
    limiting = ""
    last_ratio, growth = math.inf, 1.0
    for _ in range(max_attempts):
        traj = sample_step(step, robot_map, dt, limits / stretch, min_duration * stretch)
        compute_references(traj, spec, model)
        for rewrite in rewrites:
            rewrite(step, traj, first)
        ratio, j = speed_ratio(model, traj, limits)
        if ratio <= 1.0:
            break
        limiting = velocity_component_name(model, j)
        # a reference that follows the time law asks 1/growth of its velocity after a
        # slow-down by growth; one that gained less than half of that (in log) does not follow
        stuck = ratio > last_ratio / math.sqrt(growth)
        duration = traj.num_samples * dt * ratio * 1.02
        if stuck or duration > max_duration_s:
            raise ValueError(
                f"step {step.index} ({step.transition}): its references ask {limiting} for "
                f"{ratio:.2f} x its velocity bound "
                + (
                    f"whatever the step's pace (slowed {stretch / timing.slowdown:.2f} x): a "
                    "rewritten reference that jumps"
                    if stuck
                    else f"and slowed within them the step would last {duration:.0f} s "
                    f"(more than {max_duration_s:g} s)"
                )
            )
        # 2 % beyond the excess: the rewrite is re-sampled on another grid
        last_ratio, growth = ratio, ratio * 1.02
        stretch *= growth
    else:
        raise ValueError(
            f"step {step.index} ({step.transition}): its references still ask {limiting} for "
            f"{ratio:.2f} x its velocity bound after {max_attempts} re-timings"
        )
    traj.retimed, traj.retimed_for = stretch / timing.slowdown, limiting
    lead_in(traj, timing.lead_in_s)
    dwell(traj, timing.dwell_s)
    return traj
