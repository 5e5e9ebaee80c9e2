"""Vision in the loop of execution (thesis 000 ch. 5, §5.2.2-5.2.3, §5.3.1 plank flip): the
gripper task that carries an object to its placement is servoed on the object pose measured by
the head camera (OBJECT_POSES from ``marionette perceive``), and the head looks at the object.

PBVS on the carried object (eq. 5.1-5.3 with the object as H1). The factory marks the gripper
tasks of the placement approach ``pbvs`` (:func:`factory.visual_steps`). Their planned reference
P(t) (gripper in world) is streamed right-multiplied by a correction C (gripper frame),
R(t) = P(t) C. The controller drives the gripper it computes from its encoders onto R(t), and
whatever sits between that reference and the real object — the grasp slipping in the hand, the
arm sagging under the load, encoder offsets in the controller's model (ch. 4) — is one unknown
rigid map B with O = R B (O the object in world). A camera measurement O_m at image time t_i,
with the reference R(t_i) that was tracked then, gives B = R(t_i)^-1 O_m; the reference that puts
the object on its plan O_p(t) = P(t) X_GO (X_GO the planned grasp, constant in a grasp state) is
R' = O_p B^-1, i.e.

    C* = X_GO O_m^-1 R(t_i)                                                  (fixed point)

C moves towards C* by a fraction ``alpha`` of the geodesic per measurement (an integrator on
the measured object error, eq. 5.1 e = log(O_m^-1 O_p), which averages the camera noise) and at
most ``max_speed`` / ``max_angular_speed`` (the reference never jumps). Only measured poses and
the controller's own reference enter C*: the camera's pose error through the head cancels to
first order the way eq. 5.3 cancels it (both O_m and, through the camera, the hand).

PBVS on the approach to a grasp (§5.3.1, "the grabbing of the plank"): a gripper moving to the
pre-grasp of a handle of an object nobody holds; from there to the grasp the plan is resumed,
shifted by the correction reached (servoed, the last centimetres chased the plank the fingers
pushed: unperturbed trials grasped it 1 cm / 5° off). Its planned reference P(t) ends at P_e
(the planned pre-grasp), planned relative to the object O_p. A measurement O_m moves the
goal with the object: the gripper should end at O_m O_p^-1 P_e, i.e. the correction, expressed in
the end frame, is

    C* = P_e^-1 O_m O_p(t_i)^-1 P_e                                          (approach)

and the whole approach is streamed as R(t) = L P(t), L = P_e C P_e^-1: moved rigidly with the
object in the world (left), so that the last centimetres still run along the measured handle's
axis (a right correction would turn them by C's rotation). C integrates as above.

§5.2.3, after the servoed steps: the last correction is kept ("the planned reference shifted
using the last information available") while the gripper releases the object, then blended out
with a C2 ramp over the next step of that gripper, so no controller switch sees a jump. After a
servoed grasp the correction is kept likewise through the step that lifts the object off its
placement (the gripper still holds it there) and blended out in the next.

Gaze: the posture references of every step turn the head (its two joints, nothing else) so
that the camera's optical axis points at the planned position of the object, ramped in over the
first step — the camera then keeps the object in view throughout (the head is free in the plan).
It is a step rewrite (:func:`gaze_rewrite`): the supervisor re-times a step whose head would turn
faster than the joint's bound (a short first step asked TALOS's head for 1.8 rad/s).

Where the head alone cannot see the object — at its pitch limit with a plank standing 0.4 m
before the feet, the tags lie below the image — a servoed step leans the torso
(:func:`lean_for_view`, the camera's ``lean_joints`` in robot.yaml): the smallest lean that the
kinematics predict brings a tag into view, unhidden by the robot's links
(:mod:`marionette.perception.visibility`), ramped in and out within the step, and the rest of the
posture moved so that the tasks above it (feet, centre of mass, grippers) stay on their plan
(:func:`hold_tasks`): the lowest-priority posture can then follow the lean.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import channels, lcmt_object_poses
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.factory import approached_handle, task_error, task_jacobian
from marionette.execution.plan_steps import PlanRobotMap, Step
from marionette.execution.references import Rewrite, StepTrajectory
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.objects import TaggedBody
from marionette.perception.pbvs import activation, interpolate
from marionette.perception.visibility import LineOfSight, ViewLimits, tags_in_view


@dataclass(frozen=True)
class ServoOptions:
    """Gains and limits of the visual correction; ``noise_*`` perturb each measurement (a
    seeded camera-noise model on top of the rendered images' own error)."""

    alpha: float = 0.3  # fraction of the way to C* per measurement
    max_speed: float = 0.03  # [m/s] of the correction's translation
    max_angular_speed: float = 0.3  # [rad/s]
    # [m] larger fixed points are rejected as outliers. In the gripper frame a rotation error moves
    # the fixed point by its lever: the plank held 36° off (7°/4° encoder offsets, a slip) gave
    # fixed points over 8 cm: the 12 good measurements (0.1 px) of the carry were all rejected.
    max_correction: float = 0.15
    max_reprojection_px: float = 3.0  # measurements with a larger RMS are ignored
    noise_position_m: float = 0.0  # [m] sigma per axis
    noise_angle_rad: float = 0.0  # [rad] sigma per axis
    seed: int = 0
    lead_us: int = 20_000  # corrected samples re-sent from now + lead
    refresh_us: int = 50_000  # at most one re-send per this much controller time

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")
        if self.max_speed <= 0 or self.max_angular_speed <= 0 or self.max_correction <= 0:
            raise ValueError("max_speed, max_angular_speed and max_correction must be > 0")
        if self.noise_position_m < 0 or self.noise_angle_rad < 0:
            raise ValueError("camera noise sigmas must be >= 0")


def correction_fixed_point(X_GO_plan: pin.SE3, X_WO_measured: pin.SE3, X_WR: pin.SE3) -> pin.SE3:
    """C* = X_GO O_m^-1 R(t_i): the right correction of the gripper reference that brings the
    measured object onto its plan, given the reference ``X_WR`` tracked at the image time."""
    return X_GO_plan * X_WO_measured.inverse() * X_WR


def approach_fixed_point(X_WE_plan: pin.SE3, X_WO_measured: pin.SE3, X_WO_plan: pin.SE3) -> pin.SE3:
    """C* = P_e^-1 O_m O_p^-1 P_e: the correction, in the planned end frame P_e of an approach,
    that moves its goal with the object from where the plan put it (O_p) to where it is seen."""
    return X_WE_plan.inverse() * X_WO_measured * X_WO_plan.inverse() * X_WE_plan


def step_toward(
    C: pin.SE3, C_target: pin.SE3, alpha: float, max_dp: float, max_dtheta: float
) -> pin.SE3:
    """C exp(s log(C^-1 C*)) with s = alpha, shortened so that the translation moves at most
    ``max_dp`` and the rotation at most ``max_dtheta``."""
    xi = pin.log6(C.actInv(C_target)).vector
    s = alpha
    dp, dth = float(np.linalg.norm(xi[:3])) * s, float(np.linalg.norm(xi[3:])) * s
    if dp > max_dp:
        s *= max_dp / dp
    if dth * (s / alpha) > max_dtheta:
        s = min(s, max_dtheta / float(np.linalg.norm(xi[3:])))
    return C * pin.exp6(s * xi)


def right_multiply(
    values: np.ndarray, derivatives: np.ndarray, C: pin.SE3
) -> tuple[np.ndarray, np.ndarray]:
    """Pose rows (x y z qw qx qy qz) X -> X C and their world twists (v, ω): the point
    p + R t_C moves at v + ω × (R t_C), the rotation at the same ω."""
    out_v = values.copy()
    out_d = derivatives.copy()
    for k, row in enumerate(values):
        R = pin.Quaternion(row[3], row[4], row[5], row[6]).normalized().matrix()
        X = pin.SE3(R, row[:3]) * C
        q = pin.Quaternion(X.rotation)
        out_v[k] = [*X.translation, q.w, q.x, q.y, q.z]
        if derivatives.shape[1] == 6:
            out_d[k, :3] = derivatives[k, :3] + np.cross(derivatives[k, 3:], R @ C.translation)
    return out_v, out_d


def left_multiply(
    values: np.ndarray, derivatives: np.ndarray, L: pin.SE3
) -> tuple[np.ndarray, np.ndarray]:
    """Pose rows X -> L X (L in the world frame) and their world twists: the origin moves at
    R_L v, the rotation at R_L ω."""
    out_v = values.copy()
    out_d = derivatives.copy()
    R_L = L.rotation
    for k, row in enumerate(values):
        X = L * pin.SE3(
            pin.Quaternion(row[3], row[4], row[5], row[6]).normalized().matrix(), row[:3]
        )
        q = pin.Quaternion(X.rotation)
        out_v[k] = [*X.translation, q.w, q.x, q.y, q.z]
        if derivatives.shape[1] == 6:
            out_d[k, :3] = R_L @ derivatives[k, :3]
            out_d[k, 3:] = R_L @ derivatives[k, 3:]
    return out_v, out_d


@dataclass
class TaskCorrection:
    """The correction of one streamed gripper task during one step (used by the streamer)."""

    task: str
    servoed: bool  # updated from measurements (pbvs task)
    C_start: pin.SE3
    blend_out: bool  # ramp C_start -> identity over the step
    duration_us: int = 1
    start_utime: int = 0
    C: pin.SE3 = field(default_factory=pin.SE3.Identity)
    history: list[tuple[int, pin.SE3]] = field(default_factory=list)  # (from utime, C)
    version: int = 0
    frame: str = ""
    anchor: pin.SE3 | None = None  # set: applied as L = anchor C anchor^-1 on the left

    def at_sample(self, k: int, dt_us: int) -> pin.SE3:
        if not self.blend_out:
            return self.C
        a = activation(k * dt_us / max(self.duration_us, 1))
        return interpolate(self.C_start, pin.SE3.Identity(), a)

    def apply(
        self, values: np.ndarray, derivatives: np.ndarray, C: pin.SE3
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pose rows and twists corrected by ``C`` (a value of this correction)."""
        if self.anchor is None:
            return right_multiply(values, derivatives, C)
        return left_multiply(values, derivatives, self.anchor * C * self.anchor.inverse())

    def active_at(self, utime: int) -> pin.SE3:
        C = self.C_start
        for t, value in self.history:
            if t > utime:
                break
            C = value
        return C


class VisualServo:
    """Owns the corrections of the servoed gripper tasks across the steps of one run.

    ``bus`` delivers OBJECT_POSES; call :meth:`begin_step` when a step's references start and
    hand the result to the streamer; the streamer calls :meth:`update` as controller time
    advances (measurements are folded in there, never in the LCM thread)."""

    def __init__(
        self,
        bus: Any,
        steps: list[Step],
        specs: list[ControllerSpec],
        robot_map: PlanRobotMap,
        trajectories: dict[int, StepTrajectory],
        options: ServoOptions | None = None,
    ) -> None:
        self.steps = steps
        self.specs = specs
        self.robot_map = robot_map
        self.trajectories = trajectories
        self.options = options or ServoOptions()
        self._rng = np.random.default_rng(self.options.seed)
        self._lock = threading.Lock()
        self._pending: list[tuple[int, str, pin.SE3, float]] = []
        # gripper frame -> (last correction, its anchor: None for a held object's right correction)
        self._carried: dict[str, tuple[pin.SE3, pin.SE3 | None]] = {}
        # (correction, step, object, planned gripper -> object at the step's end, approach)
        self._current: list[tuple[TaskCorrection, Step, str, pin.SE3, bool]] = []
        self.measurements_used = 0
        self.measurements_rejected = 0
        self.trace: list[dict[str, Any]] = []  # per used measurement, for the report
        bus.subscribe(channels.OBJECT_POSES, lcmt_object_poses, self._on_objects)

    def _on_objects(self, msg: Any) -> None:
        with self._lock:
            for o in msg.objects:
                X = pin.SE3(
                    pin.Quaternion(*o.quaternion_world).normalized().matrix(),
                    np.array(o.position_world),
                )
                self._pending.append((int(o.utime), o.object_name, X, float(o.reprojection_error)))

    def end_thresholds(
        self, spec: ControllerSpec, thresholds: dict[str, float]
    ) -> dict[str, float]:
        """The end check of a step whose gripper reference is corrected by vision leaves out the
        posture: the planned configuration no longer agrees with the corrected gripper pose, and
        the posture (the lowest level, a regularisation) cannot converge onto it."""
        corrected = any(
            t.kind == "pbvs"
            or (t.frame in self._carried and not self._carried[t.frame][0].isIdentity())
            for t in spec.tasks
        )
        if not corrected:
            return thresholds
        return {
            n: v
            for n, v in thresholds.items()
            if next(t.kind for t in spec.tasks if t.name == n) != "posture"
        }

    def summary(self) -> dict[str, Any]:
        """Measurements used / rejected and the servo trace (report.json ``vision``)."""
        last = {}
        for row in self.trace:
            last[row["step"]] = row
        return {
            "measurements_used": self.measurements_used,
            "measurements_rejected": self.measurements_rejected,
            "last_per_step": {str(k): v for k, v in sorted(last.items())},
            "trace": self.trace,
        }

    # ---- per step ----------------------------------------------------------------------------
    def begin_step(
        self, step: Step, spec: ControllerSpec, start_utime: int, dt_us: int
    ) -> list[TaskCorrection]:
        """The corrections of this step's gripper tasks (empty: nothing to correct)."""
        traj = self.trajectories[step.index]
        corrections: list[TaskCorrection] = []
        self._current = []
        with self._lock:
            self._pending.clear()  # measurements of the previous step's images
        for task in spec.tasks:
            if (
                task.kind not in ("se3", "pbvs")
                or not task.streamed
                or task.frame in ("left_sole_link", "right_sole_link")
            ):
                continue
            carried = self._carried.get(task.frame)
            if task.kind != "pbvs" and carried is None:
                continue
            holds = {g.split("/")[-1]: h for g, h in step.grasps.items()}
            gripper = next((g for g in step.active_grippers if task.name == g.split("/")[-1]), None)
            approach = (
                None if gripper is None or task.name in holds else approached_handle(step, gripper)
            )
            C0, carried_anchor = carried if carried is not None else (pin.SE3.Identity(), None)
            if task.kind != "pbvs":
                anchor = carried_anchor  # kept or blended out as it was
            elif approach is not None:
                anchor = self._planned_end(traj, task.frame)  # L = P_e C P_e^-1 (module doc)
                if carried_anchor is not None:
                    # an anchored correction still on: the same L, re-anchored at this end
                    C0 = anchor.inverse() * carried_anchor * C0 * carried_anchor.inverse() * anchor
            else:
                anchor = None  # a held object: right correction
                if carried_anchor is not None:
                    # a grasp's left correction L still on: the same reference at the start, P0 C =
                    # L P0
                    P0 = self._planned_pose(traj, task.frame, 0)
                    C0 = P0.inverse() * carried_anchor * C0 * carried_anchor.inverse() * P0
            releasing = any(g.split("/")[-1] == task.name for g in step.released)
            at_contact = step.from_state.endswith(
                "_intersec"
            )  # releasing, or lifting what it just took
            # kept: releasing, lifting what it just took, or going on to the grasp from a servoed
            # pre-grasp (the plan resumed, shifted, §5.3.1)
            blend = task.kind != "pbvs" and not releasing and not at_contact and approach is None
            c = TaskCorrection(
                task.name,
                task.kind == "pbvs",
                C0,
                blend,
                int(traj.duration * 1e6),
                start_utime,
                C0,
                [(start_utime, C0)],
                frame=task.frame,
                anchor=anchor,
            )
            corrections.append(c)
            handle = holds[task.name] if task.name in holds else approach
            if task.kind == "pbvs" and gripper is not None and handle is not None:
                obj = handle.split("/")[0]
                X_GO = self._planned_grasp(traj, task.frame, obj)
                self._current.append((c, step, obj, X_GO, approach is not None))
            self._carried[task.frame] = (pin.SE3.Identity(), None) if blend else (C0, anchor)
        return corrections

    def end_step(self, corrections: list[TaskCorrection]) -> None:
        for c in corrections:
            if c.servoed:
                self._carried[c.frame] = (c.C, c.anchor)

    def _planned_end(self, traj: StepTrajectory, frame: str) -> pin.SE3:
        """P_e: the planned pose of ``frame`` at the step's end (world)."""
        return self._planned_pose(traj, frame, -1)

    def _planned_pose(self, traj: StepTrajectory, frame: str, k: int) -> pin.SE3:
        model = self.robot_map.model
        data = model.createData()
        pin.framesForwardKinematics(model, data, traj.q[k])
        return pin.SE3(data.oMf[model.getFrameId(frame)])

    def _planned_grasp(self, traj: StepTrajectory, frame: str, obj: str) -> pin.SE3:
        return self._planned_end(traj, frame).actInv(
            self.robot_map.object_pose(traj.q_plan[-1], obj)
        )

    def update(
        self, planned: dict[str, tuple[np.ndarray, np.ndarray]], dt_us: int, now_utime: int
    ) -> bool:
        """Folds the measurements received since the last call into the servoed corrections;
        True when a correction changed."""
        with self._lock:
            pending, self._pending = self._pending, []
        changed = False
        o = self.options
        for c, step, obj, X_GO, approach in self._current:
            values = planned[c.task][0]
            traj = self.trajectories[step.index] if approach else None
            for utime, name, X_WO, reproj in pending:
                if name != obj:
                    continue
                if reproj > o.max_reprojection_px or utime < c.start_utime:
                    self.measurements_rejected += 1
                    continue
                if o.noise_position_m > 0 or o.noise_angle_rad > 0:
                    X_WO = X_WO * pin.exp6(
                        np.concatenate(
                            [
                                self._rng.normal(0, o.noise_position_m, 3),
                                self._rng.normal(0, o.noise_angle_rad, 3),
                            ]
                        )
                    )
                k = int(np.clip((utime - c.start_utime) // dt_us, 0, len(values) - 1))
                row = values[k]
                P = pin.SE3(
                    pin.Quaternion(row[3], row[4], row[5], row[6]).normalized().matrix(), row[:3]
                )
                if traj is not None:  # approaching
                    X_WO_plan = self.robot_map.object_pose(
                        traj.q_plan[min(k, len(traj.q_plan) - 1)], obj
                    )
                    C_star = approach_fixed_point(c.anchor, X_WO, X_WO_plan)
                else:
                    C_star = correction_fixed_point(X_GO, X_WO, P * c.active_at(utime))
                if np.linalg.norm(C_star.translation) > o.max_correction:
                    self.measurements_rejected += 1
                    continue
                dt = max(now_utime - (c.history[-1][0] if c.history else now_utime), 0) * 1e-6
                dt = min(max(dt, 0.01), 0.2)
                c.C = step_toward(c.C, C_star, o.alpha, o.max_speed * dt, o.max_angular_speed * dt)
                c.history.append((now_utime, c.C))
                c.version += 1
                changed = True
                self.measurements_used += 1
                # measured object vs its plan: where the planned gripper would hold it, or where
                # the plan put it (an approach)
                X_plan = X_WO_plan if approach else P * X_GO
                err = X_plan.inverse() * X_WO
                self.trace.append(
                    {
                        "utime": utime,
                        "step": step.index,
                        "approach": approach,
                        "object_error_m": float(
                            np.linalg.norm(X_WO.translation - X_plan.translation)
                        ),
                        "object_error_deg": math.degrees(
                            float(np.linalg.norm(pin.log3(err.rotation)))
                        ),
                        "correction_m": float(np.linalg.norm(c.C.translation)),
                        "correction_deg": math.degrees(
                            float(np.linalg.norm(pin.log3(c.C.rotation)))
                        ),
                    }
                )
        return changed


# ---- gaze through the posture references ---------------------------------------------------


def _image_point(model: pin.Model, data: pin.Data, fid: int, q: np.ndarray, p_W: np.ndarray):
    pin.framesForwardKinematics(model, data, q)
    p_C = data.oMf[fid].actInv(p_W)
    return p_C[:2] / max(p_C[2], 1e-3)


def aim_camera(
    model: pin.Model,
    data: pin.Data,
    fid: int,
    q: np.ndarray,
    idx: list[int],
    bounds: tuple[np.ndarray, np.ndarray],
    active: list[int],
    target: np.ndarray,
    radius: float = 0.0,
) -> np.ndarray:
    """The joints ``idx`` of ``q`` (those listed in ``active`` free, within ``bounds``) that
    bring ``target``'s image point (normalised, camera frame ``fid``) within ``radius`` of the
    centre (0: onto it): Gauss-Newton with a finite-difference Jacobian. ``q`` is updated."""
    lo, hi = bounds
    x = np.clip(q[idx], lo, hi)
    for _ in range(5):
        q[idx] = x
        p = _image_point(model, data, fid, q, target)
        e = p * max(0.0, 1.0 - radius / max(float(np.linalg.norm(p)), 1e-12)) if radius else p
        J = np.empty((2, len(active)))
        for c, j in enumerate(active):
            qd = q.copy()
            qd[idx[j]] += 1e-6
            J[:, c] = (_image_point(model, data, fid, qd, target) - p) / 1e-6
        step = np.linalg.lstsq(J, e, rcond=None)[0]
        for c, j in enumerate(active):
            x[j] = np.clip(x[j] - step[c], lo[j], hi[j])
    q[idx] = x
    return x


def _joint_bounds(model: pin.Model, names: tuple[str, ...]) -> tuple[list[int], list[int], tuple]:
    idx = [model.joints[model.getJointId(j)].idx_q for j in names]
    vdx = [model.joints[model.getJointId(j)].idx_v for j in names]
    margin = 0.03  # [rad] inside the limits: the controller's joint-limit task keeps off them
    lo, hi = model.lowerPositionLimit[idx] + margin, model.upperPositionLimit[idx] - margin
    return idx, vdx, (lo, hi)


def head_gaze_posture(
    model: pin.Model,
    traj: StepTrajectory,
    targets_W: np.ndarray,
    camera_frame: str,
    joints: tuple[str, ...] = ("head_1_joint", "head_2_joint"),
    extra_joints: tuple[str, ...] = (),
    ramp_in: bool = False,
    every: int = 20,
    tolerance: float = 0.2,
) -> None:
    """Rewrites the gaze joints of ``traj.references['posture']`` so that the optical axis (z)
    of ``camera_frame`` points at ``targets_W`` (N x 3, one per sample): the two head joints for
    the two image coordinates (x/z, y/z), Gauss-Newton (:func:`aim_camera`) every ``every``
    samples and linear in between; when the head reaches its limits and the target stays more
    than ``tolerance`` (normalised image coordinate) off the centre, ``extra_joints`` join in,
    only as far as bringing it ``tolerance`` from the centre (0.2 ≈ 11°). The plank demo does
    not centre its object so (the torso pitch needed views its tagged face edge-on and behind
    the hand): :func:`lean_for_view` leans only as far as tags come into view. ``ramp_in``
    blends from the planned posture over the step with a C2 ramp. Velocities: central
    differences."""
    values, derivs = traj.references["posture"]
    names = tuple(joints) + tuple(extra_joints)
    idx, vdx, (lo, hi) = _joint_bounds(model, names)
    fid = model.getFrameId(camera_frame)
    data = model.createData()
    n = len(values)
    ks = list(range(0, n, every)) + ([n - 1] if (n - 1) % every else [])

    out = np.empty((len(ks), len(names)))
    for i, k in enumerate(ks):
        q = values[k].copy()
        x = aim_camera(model, data, fid, q, idx, (lo, hi), list(range(len(joints))), targets_W[k])
        if np.linalg.norm(_image_point(model, data, fid, q, targets_W[k])) > tolerance and (
            extra_joints
        ):
            free = [j for j in range(len(joints)) if lo[j] + 1e-6 < x[j] < hi[j] - 1e-6]
            x = aim_camera(
                model,
                data,
                fid,
                q,
                idx,
                (lo, hi),
                free + list(range(len(joints), len(names))),
                targets_W[k],
                radius=tolerance,
            )
        out[i] = x
    full = np.column_stack([np.interp(np.arange(n), ks, out[:, j]) for j in range(len(names))])
    if ramp_in:
        a = np.array([activation(k / max(n - 1, 1)) for k in range(n)])[:, None]
        full = values[:, idx] + a * (full - values[:, idx])
    values[:, idx] = full
    d = np.zeros_like(full)
    d[1:-1] = (full[2:] - full[:-2]) / (2 * traj.dt)
    derivs[:, vdx] = d


@dataclass
class ObjectView:
    """Whether the camera would detect ``body``'s tags (:func:`.visibility.tags_in_view`, the
    robot's links hiding them) with the robot at ``q`` and the object at ``X_WO``: ``limits``
    from the most demanding (margins that keep a tag in view when the object is centimetres off
    its plan) to the least."""

    model: pin.Model
    camera_frame: str
    body: TaggedBody
    intrinsics: CameraIntrinsics
    sight: LineOfSight
    limits: tuple[ViewLimits, ...]  # most demanding first

    def __post_init__(self) -> None:
        self.data = self.model.createData()
        self.fid = self.model.getFrameId(self.camera_frame)

    def seen(self, q: np.ndarray, X_WO: pin.SE3, level: int = 0) -> int:
        """Tags detected under ``limits[level]``."""
        pin.framesForwardKinematics(self.model, self.data, q)
        self.sight.update(self.data)
        return tags_in_view(
            self.data.oMf[self.fid],
            X_WO,
            self.body,
            self.intrinsics,
            self.limits[level],
            self.sight,
        )


def hold_tasks(
    model: pin.Model,
    data: pin.Data,
    data_ref: pin.Data,
    q: np.ndarray,
    tasks: list[TaskSpec],
    fixed_v: list[int],
    iterations: int = 6,
) -> np.ndarray:
    """``q`` moved (Gauss-Newton, least norm, the velocity components ``fixed_v`` kept) until
    ``tasks`` are where they are at the configuration whose kinematics ``data_ref`` holds
    (frames and centre of mass): the rest of the body making room for a joint that was moved —
    the legs shift the pelvis back under a torso leaning forward, the arm keeps its gripper."""
    free = np.setdiff1d(np.arange(model.nv), fixed_v)
    q = q.copy()
    for _ in range(iterations):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        pin.centerOfMass(model, data, q, False)
        rows = [
            (e, J)
            for t in tasks
            if (e := task_error(model, data, t, q, data_ref)) is not None
            and (J := task_jacobian(model, data, t, q)) is not None
        ]
        if not rows:
            break
        e = np.concatenate([r[0] for r in rows])
        if float(np.linalg.norm(e)) < 1e-7:
            break
        J = np.vstack([r[1] for r in rows])
        dq = np.zeros(model.nv)
        dq[free] = -np.linalg.lstsq(J[:, free], e, rcond=1e-8)[0]
        q = pin.integrate(model, q, dq)
    return q


def lean_for_view(
    traj: StepTrajectory,
    targets_W: np.ndarray,
    object_poses: list[pin.SE3],
    view: ObjectView,
    head_joints: tuple[str, ...],
    lean_joint: str,
    held: Sequence[TaskSpec] = (),
    allowed: Callable[[int, np.ndarray], bool] | None = None,
    samples: int = 13,
    increment: float = 0.05,
    ramp: float = 0.25,
) -> float:
    """Leans the step's posture reference on ``lean_joint`` (a torso pitch) so that the head,
    aimed at ``targets_W`` (:func:`aim_camera`, its joints ``head_joints``), sees the object's
    tags where it would not with the planned posture: at ``samples`` points evenly spread over
    the step (the same path points whatever its pace, so that re-timing it scales the lean's
    velocity and converges) the smallest lean (in
    ``increment`` steps, either sign, within the joint's limits) that shows a tag (``view``);
    the step takes the largest of them, ramped in over its first ``ramp`` and out over its last
    ``ramp`` (C2), so that it starts and ends on the plan and no controller switch sees a jump.
    Samples no lean makes see (the object hidden by the hand that reaches it) do not count; the
    view's limits are tried from the most demanding, the first any sample meets is used.
    The rest of the posture makes room for the lean (:func:`hold_tasks`): the ``held`` tasks —
    those above the posture, the feet, the centre of mass, the grippers — stay where the plan
    has them, so that the posture, the lowest priority, can follow the lean instead of sharing
    it with the legs it would pull off balance (a lean-only reference was followed by less than
    half). ``allowed(k, q)`` (sample, leaned robot configuration) refuses a lean the robot may
    not take there (a free hand brought into the table): a lean is kept only if every sample of
    the ramped profile is allowed, else the next smaller one. Returns the lean applied [rad] (0:
    the head alone sees it, or nothing helps, or nothing is allowed)."""
    model = view.model
    values, derivs = traj.references["posture"]
    idx, hdx, bounds = _joint_bounds(model, tuple(head_joints))
    (li,), (lv,), (lean_lo, lean_hi) = _joint_bounds(model, (lean_joint,))
    llo, lhi = float(lean_lo[0]), float(lean_hi[0])
    fixed_v = [*hdx, lv]
    n = len(values)
    ks = sorted({round(x) for x in np.linspace(0, n - 1, max(samples, 2))})
    data, data_ref = model.createData(), model.createData()

    def leaned(k: int, delta: float) -> np.ndarray:
        q = values[k].copy()
        q[li] = float(np.clip(q[li] + delta, llo, lhi))
        if delta == 0.0 or not held:
            return q
        pin.framesForwardKinematics(model, data_ref, values[k])
        pin.centerOfMass(model, data_ref, values[k], False)
        return hold_tasks(model, data, data_ref, q, list(held), fixed_v)

    aimed: dict[tuple[int, float], np.ndarray] = {}

    def aimed_at(k: int, delta: float) -> np.ndarray:
        if (k, delta) not in aimed:
            q = leaned(k, delta)
            aim_camera(model, data, view.fid, q, idx, bounds, list(range(len(idx))), targets_W[k])
            aimed[k, delta] = q
        return aimed[k, delta]

    needed: list[float] = []
    for level in range(len(view.limits)):  # the most demanding view any lean gives
        for k in ks:
            for m in range(int((lhi - llo) / increment) + 1):
                delta = increment * ((m + 1) // 2) * (1 if m % 2 else -1) if m else 0.0
                if not llo <= values[k, li] + delta <= lhi:
                    continue
                q = aimed_at(k, delta)
                if view.seen(q, object_poses[k], level) and (
                    allowed is None or delta == 0.0 or allowed(k, q)
                ):
                    needed.append(delta)
                    break
        if needed:
            break
    lean = max(needed, key=abs, default=0.0)
    r = max(ramp * (n - 1), 1.0)
    rows = np.empty((0, model.nq))
    while lean != 0.0:
        weights = [activation(k / r) * activation((n - 1 - k) / r) for k in ks]
        rows = np.array([leaned(k, lean * w) for k, w in zip(ks, weights)])
        if allowed is None or all(allowed(k, q) for k, q in zip(ks, rows)):
            break
        lean = round(lean - increment * np.sign(lean), 9)
    if lean == 0.0:
        return 0.0
    full = np.column_stack([np.interp(np.arange(n), ks, rows[:, j]) for j in range(model.nq)])
    for j in range(1, model.njoints):
        joint = model.joints[j]
        if joint.nq == 7:  # a free flyer: where the body went (the posture does not follow it)
            block = full[:, joint.idx_q : joint.idx_q + 7]
            block[:, 3:] /= np.linalg.norm(block[:, 3:], axis=1, keepdims=True)
            values[:, joint.idx_q : joint.idx_q + 7] = block
        elif joint.nq == 1 and joint.idx_q not in idx:
            values[:, joint.idx_q] = full[:, joint.idx_q]
            derivs[1:-1, joint.idx_v] = (full[2:, joint.idx_q] - full[:-2, joint.idx_q]) / (
                2 * traj.dt
            )
    return float(lean)


def planned_object_positions(traj: StepTrajectory, robot_map: PlanRobotMap, obj: str) -> np.ndarray:
    """(N, 3) planned world position of ``obj`` at every sample of the step."""
    return np.array([robot_map.object_pose(q, obj).translation for q in traj.q_plan])


@dataclass(frozen=True)
class Lean:
    """What the gaze needs to lean the torso on the servoed steps (:func:`lean_for_view`): the
    camera's ``view`` of the object, the head's joints, the lean joint, and per servoed step the
    tasks above its posture that the lean keeps where the plan has them; ``allowed`` refuses
    leaned configurations (collisions the plan did not have)."""

    view: ObjectView
    head_joints: tuple[str, ...]
    joint: str
    held: dict[int, list[TaskSpec]]
    # (full plan configuration, leaned robot configuration) -> may the robot take it there
    allowed: Callable[[np.ndarray, np.ndarray], bool] | None = None


def gaze_rewrite(
    robot_map: PlanRobotMap, obj: str, camera_frame: str, lean: Lean | None = None
) -> Rewrite:
    """A step rewrite (:func:`references.shaped_trajectory`): the head of the step's posture
    reference looks at the planned ``obj``, ramped in over the first step run (so that its
    controller starts where the robot is). With ``lean``, the servoed steps first lean the
    torso where the head alone would not see the object (:func:`lean_for_view`). The supervisor
    re-times a step whose head would then turn faster than its bound."""

    def rewrite(step: Step, traj: StepTrajectory, first: bool) -> None:
        targets = planned_object_positions(traj, robot_map, obj)
        if lean is not None and step.index in lean.held:
            poses = [robot_map.object_pose(q, obj) for q in traj.q_plan]
            allowed = lean.allowed

            def allowed_at(k: int, q: np.ndarray) -> bool:
                return allowed is None or allowed(traj.q_plan[k], q)

            traj.lean = lean_for_view(
                traj,
                targets,
                poses,
                lean.view,
                lean.head_joints,
                lean.joint,
                lean.held[step.index],
                allowed_at,
            )
        head_gaze_posture(robot_map.model, traj, targets, camera_frame, ramp_in=first)

    return rewrite


def add_gaze(
    trajectories: dict[int, StepTrajectory],
    steps: list[Step],
    robot_map: PlanRobotMap,
    obj: str,
    camera_frame: str,
) -> None:
    """:func:`gaze_rewrite` applied to already sampled ``trajectories`` of ``steps`` (the first
    of them ramps the gaze in), without re-timing."""
    rewrite = gaze_rewrite(robot_map, obj, camera_frame)
    for i, step in enumerate(steps):
        rewrite(step, trajectories[step.index], i == 0)
