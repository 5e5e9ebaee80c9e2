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

The hand in that fixed point is the one the controller commands at the image time (forward
kinematics of its commanded joints), not the reference R(t_i): a hand held back by a joint limit
or a task above it does not follow the correction, and read against the reference the unfollowed
part would be taken for the object off in the hand, again at every measurement (the correction
wound up to 10 cm in a carry). The commanded hand does not move with what it does not follow.
A measurement is used only while the encoders put the hand within ``max_tracking_*`` of the
commanded one: a hand lagging a fast carry by centimetres would be read as the object off in
it. The steady error of the joints under the load (millimetres) stays in B and is corrected.

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

PBVS on a hand-over (§5.3.1: "instead of relying on the perceived position of the first gripper
to position the second, the controller was directly using the AprilTags on the plank"): a
gripper approaching the pre-grasp of a handle of an object another gripper holds. Its task is
relative to the holding gripper H: X_HG(t), and the plank is where the holding hand really has
it, not where the controller's model of that hand puts it (a wrist at its torque limit sags
centimetres below its command, while the controller, computing on its commands, reports the
hand-over converged). A measurement O_m, with the hand H_c(t_i) the controller commanded then,
says where the object is in the commanded holding hand; the approaching gripper is placed
relative to the object as planned when the relative reference is streamed as D X_HG(t), with

    D* = H_c(t_i)^-1 O_m X_HO^-1                                             (hand-over)

(X_HO the planned grasp of the holding gripper): a left correction in the holding gripper's
frame, kept on to the grasp like an approach's, read in the world afterwards.

§5.2.3, after the servoed steps: the last correction is kept ("the planned reference shifted
using the last information available") while the gripper releases the object, then blended out
with a C2 ramp over the next step of that gripper, so no controller switch sees a jump. After a
servoed grasp the correction is kept likewise through the step that lifts the object off its
placement (the gripper still holds it there) and blended out in the next.

What the camera sees is used beyond the steps the thesis servoes (:func:`servoed_tasks`,
:func:`looks_before_approach`). The object's error in the hand belongs to the grasp, not to a
step: the whole carry that ends in a servoed placement is servoed under the same grasp, so that
what the camera saw during the carry still holds when the holding hand hides the object in the
placement (it starts from the plan, blending out what the grasp's left correction had; the first
measurement takes over). An object no gripper touches lies where it was last seen: the servo
keeps those poses, and the approach to it starts from them (the reaching hand often hides the
object in a short approach), going as fast as it must to arrive by ``approach_settle`` of the
step. Each correction moves towards its filtered target within its speed limits for the time
elapsed, whatever the number of measurements that arrive at once.

Gaze: the posture references of every step turn the head (its two joints, nothing else) so
that the camera's optical axis points at the planned position of the object, ramped in over the
first step — the camera then keeps the object in view throughout (the head is free in the plan).
It is a step rewrite (:func:`gaze_rewrite`): the supervisor re-times a step whose head would turn
faster than the joint's bound (a short first step asked TALOS's head for 1.8 rad/s).

Where the head alone cannot see the object — at its pitch limit with a plank standing 0.4 m
before the feet, the tags lie below the image — a step where the servo looks (a servoed step, or
the one before an approach) leans the torso (:func:`lean_for_view`, the camera's
``lean_joints`` in robot.yaml): the smallest lean that the
kinematics predict brings a tag into view, unhidden by the robot's links
(:mod:`marionette.perception.visibility`), ramped in and out within the step, and the rest of the
posture moved so that the tasks above it (feet, centre of mass, grippers) stay on their plan
(:func:`hold_tasks`): the lowest-priority posture can then follow the lean.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import channels, lcmt_object_poses, lcmt_robot_command, lcmt_robot_state
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.factory import (
    approached_handle,
    task_error,
    task_jacobian,
    task_name,
    visual_approach_kind,
)
from marionette.execution.plan_steps import PlanRobotMap, Step
from marionette.execution.references import Rewrite, StepTrajectory
from marionette.models.xml_util import matrix_to_quat_wxyz
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.kinematics import StateError, StateHistory
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
    # An approach to an object at rest may go faster, so as to reach the object's measured pose
    # by ``approach_settle`` of the step: what the camera saw before a short approach (0.5 s)
    # whose reaching hand hides the object is all it gets (the free hand carries nothing).
    max_approach_speed: float = 0.15  # [m/s]
    max_approach_angular_speed: float = 1.0  # [rad/s]
    approach_settle: float = 0.8
    max_reprojection_px: float = 3.0  # measurements with a larger RMS are ignored
    # A held object's measurement is read against the hand the controller commands at the image
    # time (the forward kinematics of its commanded joints: what the task level achieved, not
    # the reference it was asked, which a hand held back by a joint limit does not follow: read
    # against the reference, the correction wound up to 10 cm) and is used only while the
    # encoders put the hand within this of that commanded hand: a hand lagging a fast carry by
    # 2-6 cm, or an actuator at its torque, would be read as the object off in the hand. The
    # steady error of the joints under the plank's weight, 5-10 mm / 1-2°, stays in (corrected).
    max_tracking_m: float = 0.02
    max_tracking_rad: float = 0.09
    noise_position_m: float = 0.0  # [m] sigma per axis
    noise_angle_rad: float = 0.0  # [rad] sigma per axis
    seed: int = 0
    # Servo a hand-over's approach on the object in the holding hand (:func:`handover_approaches`).
    # Off by default: on welded grasps it followed a holding wrist sagging 8 cm / 21 deg at its
    # torque limit, and the receiving arm's swing moved the stance (plank plan 116: the feet 29 mm
    # off their tasks); friction grasps, which miss the handle without it, turn it on.
    handovers: bool = False
    lead_us: int = 20_000  # corrected samples re-sent from now + lead
    refresh_us: int = 50_000  # at most one re-send per this much controller time

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")
        if min(self.max_speed, self.max_angular_speed, self.max_correction) <= 0:
            raise ValueError("max_speed, max_angular_speed and max_correction must be > 0")
        if self.max_approach_speed < self.max_speed:
            raise ValueError("max_approach_speed must be >= max_speed")
        if self.max_approach_angular_speed < self.max_angular_speed:
            raise ValueError("max_approach_angular_speed must be >= max_angular_speed")
        if not 0.0 < self.approach_settle <= 1.0:
            raise ValueError(f"approach_settle must be in (0, 1], got {self.approach_settle}")
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


def handover_fixed_point(X_HO_plan: pin.SE3, X_WO_measured: pin.SE3, X_WH: pin.SE3) -> pin.SE3:
    """D* = H_c^-1 O_m X_HO^-1: the left correction, in the holding gripper's frame, of a task
    relative to it that puts the approaching gripper where the plan has it relative to the
    measured object, given the holding gripper ``X_WH`` commanded at the image time."""
    return X_WH.inverse() * X_WO_measured * X_HO_plan.inverse()


def _objects_touched(step: Step) -> set[str]:
    """The objects a gripper holds at some point of ``step`` (handles are ``object/handle``)."""
    return {
        h.split("/")[0]
        for grasps in (step.grasps, step.grasps_from, step.grasps_to)
        for h in grasps.values()
    }


def servoed_tasks(
    steps: Sequence[Step], specs: Sequence[ControllerSpec], handovers: bool = False
) -> dict[int, set[str]]:
    """Step index -> the gripper tasks whose reference vision corrects in that step: the
    factory's ``pbvs`` tasks (a servoed approach, a servoed placement) and, before a servoed
    placement, the task of the gripper that carries the object to it under the same grasp. The
    object's error in the hand is one of the grasp (a slip, the arm sagging, an encoder
    offset), not of a step: it is measured whenever the camera sees the object during the
    carry and kept until the placement, where the holding hand may hide the object at every
    lean (a transit that splits the placement blended out what the first half had reached)."""
    out: dict[int, set[str]] = {}
    for i, (step, spec) in enumerate(zip(steps, specs)):
        names = {t.name for t in spec.tasks if t.kind == "pbvs"}
        if handovers:
            names |= set(handover_approaches(step, spec))
        for gripper, handle in step.grasps.items():
            name = task_name(gripper)
            if name in names:
                continue
            for later, later_spec in zip(steps[i + 1 :], specs[i + 1 :]):
                if later.grasps.get(gripper) != handle:
                    break
                if any(t.kind == "pbvs" and t.name == name for t in later_spec.tasks):
                    names.add(name)
                    break
        if names:
            out[step.index] = names
    return out


def handover_approaches(step: Step, spec: ControllerSpec) -> dict[str, str]:
    """The relative gripper tasks of ``step`` that approach the pre-grasp of a handle of an object
    the task's other gripper holds all along the step (a hand-over), servoed like an approach to
    an object at rest (:data:`factory.VISUAL_APPROACH_WAYPOINTS`): task name -> the holding
    gripper's frame."""
    frames = {task_name(g): g for g in step.active_grippers}
    holders = {h.split("/")[0] for h in step.grasps.values()}
    out: dict[str, str] = {}
    for t in spec.tasks:
        gripper = frames.get(t.name)
        if t.kind != "relative_se3" or not t.streamed or gripper is None:
            continue
        handle = approached_handle(step, gripper)
        if handle is None or visual_approach_kind(step, gripper) is None:
            continue
        if handle.split("/")[0] in holders and t.frame_b:
            out[t.name] = t.frame_b
    return out


def looks_before_approach(steps: Sequence[Step], specs: Sequence[ControllerSpec]) -> set[int]:
    """Steps whose next step is a servoed approach to an object that lies at rest in both: what
    the camera sees of it there is still true when the approach starts (:class:`VisualServo`
    keeps it), which helps an approach whose reaching hand hides the object."""
    out: set[int] = set()
    for step, nxt, nxt_spec in zip(steps, steps[1:], specs[1:]):
        for gripper in nxt.active_grippers:
            handle = approached_handle(nxt, gripper)
            if handle is None or not any(
                t.kind == "pbvs" and t.name == task_name(gripper) for t in nxt_spec.tasks
            ):
                continue
            obj = handle.split("/")[0]
            if obj not in _objects_touched(step) | _objects_touched(nxt):
                out.add(step.index)
    return out


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
    p + R t_C moves at v + ω × (R t_C), the rotation at the same ω. Vectorised over the rows:
    a re-sent second of a servoed task is 1000 of them (pose by pose, 20-30 ms of the
    interpreter's lock, and seconds on a loaded machine while the stream ran dry)."""
    q = _unit_rows(values)
    Rt = _rotated(q, C.translation)
    out_v = values.copy()
    out_v[:, :3] = values[:, :3] + Rt
    out_v[:, 3:7] = _quaternion_products(q, matrix_to_quat_wxyz(C.rotation))
    out_d = derivatives.copy()
    if derivatives.shape[1] == 6:
        out_d[:, :3] = derivatives[:, :3] + np.cross(derivatives[:, 3:], Rt)
    return out_v, out_d


def left_multiply(
    values: np.ndarray, derivatives: np.ndarray, L: pin.SE3
) -> tuple[np.ndarray, np.ndarray]:
    """Pose rows X -> L X (L in the world frame) and their world twists: the origin moves at
    R_L v, the rotation at R_L ω (vectorised over the rows, as :func:`right_multiply`)."""
    R_L = L.rotation
    out_v = values.copy()
    out_v[:, :3] = values[:, :3] @ R_L.T + L.translation
    out_v[:, 3:7] = _quaternion_products(matrix_to_quat_wxyz(R_L), _unit_rows(values))
    out_d = derivatives.copy()
    if derivatives.shape[1] == 6:
        out_d[:, :3] = derivatives[:, :3] @ R_L.T
        out_d[:, 3:] = derivatives[:, 3:] @ R_L.T
    return out_v, out_d


def _unit_rows(values: np.ndarray) -> np.ndarray:
    """The rows' quaternions (w x y z), normalised."""
    q = values[:, 3:7]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _quaternion_products(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products a ⊗ b of quaternions (w x y z): rows, or one quaternion and rows."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def _rotated(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The vector ``t`` rotated by each unit quaternion row of ``q`` (w x y z)."""
    w, u = q[:, :1], q[:, 1:]
    c = np.cross(u, t)
    return t + 2.0 * w * c + 2.0 * np.cross(u, c)


@dataclass
class TaskCorrection:
    """The correction of one streamed gripper task during one step (used by the streamer)."""

    task: str
    servoed: bool  # updated from measurements (:func:`servoed_tasks`)
    C_start: pin.SE3
    # ramp C_start -> identity over the step; a servoed correction leaves the ramp where it is
    # at its first measurement
    blend_out: bool
    duration_us: int = 1
    start_utime: int = 0
    C: pin.SE3 = field(default_factory=pin.SE3.Identity)
    history: list[tuple[int, pin.SE3]] = field(default_factory=list)  # (from utime, C)
    version: int = 0
    frame: str = ""
    anchor: pin.SE3 | None = None  # set: applied as L = anchor C anchor^-1 on the left
    # set: the task is relative to this (holding) gripper's frame and C is applied on the left in
    # it; ``holder_end``: that frame's planned pose at the step's end (where C is read in the
    # world by the next step: L = holder_end C holder_end^-1)
    holder: str = ""
    holder_end: pin.SE3 | None = None
    target: pin.SE3 | None = None  # the filtered fixed point C follows (None: nothing measured)
    moved_utime: int = 0  # controller time C last moved towards the target
    folded: int = 0  # measurements folded into the target
    C_start_measured: bool = False  # C_start carries earlier measurements' average

    def at_sample(self, k: int, dt_us: int) -> pin.SE3:
        if not self.blend_out:
            return self.C
        a = activation(k * dt_us / max(self.duration_us, 1))
        return interpolate(self.C_start, pin.SE3.Identity(), a)

    def apply(
        self, values: np.ndarray, derivatives: np.ndarray, C: pin.SE3
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pose rows and twists corrected by ``C`` (a value of this correction)."""
        if self.holder:
            return left_multiply(values, derivatives, C)
        if self.anchor is None:
            return right_multiply(values, derivatives, C)
        return left_multiply(values, derivatives, self.anchor * C * self.anchor.inverse())

    def carried(self, C: pin.SE3) -> tuple[pin.SE3, pin.SE3 | None]:
        """(C, anchor) as the next step of this gripper takes it over: an anchored (world) left
        correction, or a right one (anchor None)."""
        return (C, self.holder_end) if self.holder else (C, self.anchor)

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

    AT_REST_KEPT = 30  # measurements of an object at rest kept for the approach to it

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
        # (image utime, object, pose in world, reprojection error [px], from the at-rest store)
        self._pending: list[tuple[int, str, pin.SE3, float, bool]] = []
        self._servoed = servoed_tasks(steps, specs, self.options.handovers)
        # object nobody has touched since -> its latest measurements (utime, pose, reprojection)
        self._at_rest: dict[str, list[tuple[int, pin.SE3, float]]] = {}
        self._touched: set[str] = set()  # objects a gripper holds in the current step
        self._step_start = 0
        # gripper frame -> (last correction, its anchor: None for a held object's right correction)
        self._carried: dict[str, tuple[pin.SE3, pin.SE3 | None]] = {}
        # (correction, step, object, planned gripper -> object at the step's end (a hand-over:
        # holding gripper -> object), approach)
        self._current: list[tuple[TaskCorrection, Step, str, pin.SE3, bool]] = []
        self.measurements_used = 0
        self.measurements_rejected = 0
        self.measurements_hand_off_command = 0  # held object, the hand away from the commanded one
        self.states_rejected = 0  # ROBOT_STATE messages that do not fit the model
        self._states: StateHistory | None = None
        # (utime, joint names, commanded positions): the controller's ROBOT_COMMAND
        self._commands: deque[tuple[int, tuple[str, ...], np.ndarray]] = deque(maxlen=200)
        self._command_index: dict[tuple[str, ...], np.ndarray] = {}
        if robot_map is not None:  # the hand measured and commanded at an image's time
            self._states = StateHistory(robot_map.model)
            bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)
            bus.subscribe(channels.ROBOT_COMMAND, lcmt_robot_command, self._on_command)
        self.trace: list[dict[str, Any]] = []  # per used measurement, for the report
        bus.subscribe(channels.OBJECT_POSES, lcmt_object_poses, self._on_objects)

    def _on_objects(self, msg: Any) -> None:
        with self._lock:
            for o in msg.objects:
                X = pin.SE3(
                    pin.Quaternion(*o.quaternion_world).normalized().matrix(),
                    np.array(o.position_world),
                )
                self._pending.append(
                    (int(o.utime), o.object_name, X, float(o.reprojection_error), False)
                )

    def _on_state(self, msg: Any) -> None:
        assert self._states is not None
        try:
            self._states.add_state(msg)
        except StateError:
            self.states_rejected += 1  # reported: the controller's state should fit its model

    def _on_command(self, msg: Any) -> None:
        with self._lock:
            self._commands.append(
                (int(msg.utime), tuple(msg.joint_name), np.asarray(msg.joint_position, float))
            )

    def _hand_poses(self, frame: str, utime: int) -> tuple[pin.SE3, pin.SE3] | None:
        """(measured, commanded) pose of the gripper frame at the robot state and command
        nearest ``utime`` (each within 20 ms; the commanded one on the state's base), or None."""
        if self._states is None:
            return None
        found = self._states.nearest(utime)
        with self._lock:
            command = min(self._commands, key=lambda c: abs(c[0] - utime), default=None)
        if found is None or command is None:
            return None
        (q, t), (tc, names, positions) = found, command
        if abs(t - utime) > 20_000 or abs(tc - utime) > 20_000:
            return None
        model = self.robot_map.model
        idx = self._command_index.get(names)
        if idx is None:
            idx = np.array([model.joints[model.getJointId(n)].idx_q for n in names])
            self._command_index[names] = idx
        q_cmd = q.copy()
        q_cmd[idx] = positions
        fid = model.getFrameId(frame)
        return self._states.frame_pose_at(fid, q), self._states.frame_pose_at(fid, q_cmd)

    def end_thresholds(
        self, step: Step, spec: ControllerSpec, thresholds: dict[str, float]
    ) -> dict[str, float]:
        """The end check of a step whose gripper reference is corrected by vision leaves out the
        posture: the planned configuration no longer agrees with the corrected gripper pose, and
        the posture (the lowest level, a regularisation) cannot converge onto it."""
        servoed = self._servoed.get(step.index, set())
        corrected = any(
            t.name in servoed
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
        last: dict[int, dict[str, Any]] = {}
        used: dict[int, list[int]] = {}  # step -> [used, of which seen at rest before it]
        for row in self.trace:
            last[row["step"]] = row
            counts = used.setdefault(row["step"], [0, 0])
            counts[0] += 1
            counts[1] += int(row["at_rest"])
        return {
            "measurements_used": self.measurements_used,
            "measurements_rejected": self.measurements_rejected,
            "measurements_hand_off_command": self.measurements_hand_off_command,
            "states_rejected": self.states_rejected,
            "last_per_step": {str(k): v for k, v in sorted(last.items())},
            "used_per_step": {str(k): v for k, v in sorted(used.items())},
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
        servoed_here = self._servoed.get(step.index, set())
        touched = _objects_touched(step)
        self._take_pending()  # the previous step's images: only what they saw at rest is kept
        with self._lock:
            for obj in touched:  # a gripper holds it: where it lay is history
                self._at_rest.pop(obj, None)
            self._touched, self._step_start = touched, start_utime
        for task in spec.tasks:
            if (
                task.kind not in ("se3", "pbvs", "relative_se3")
                or not task.streamed
                or task.frame in ("left_sole_link", "right_sole_link")
            ):
                continue
            servoed = task.name in servoed_here
            carried = self._carried.get(task.frame)
            if not servoed and carried is None:
                continue
            holds = {task_name(g): h for g, h in step.grasps.items()}
            gripper = next((g for g in step.active_grippers if task.name == task_name(g)), None)
            approach = (
                None if gripper is None or task.name in holds else approached_handle(step, gripper)
            )
            C0, carried_anchor = carried if carried is not None else (pin.SE3.Identity(), None)
            holder = task.frame_b if task.kind == "relative_se3" else ""
            if holder:
                # left in the holding gripper's frame H: what was carried, read in H at the start
                anchor = None
                if carried is not None:
                    H0 = self._planned_pose(traj, holder, 0)
                    L = self._world_left(C0, carried_anchor, traj, task.frame)
                    C0 = H0.inverse() * L * H0
            elif not servoed:
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
            releasing = any(task_name(g) == task.name for g in step.released)
            at_contact = step.from_state.endswith(
                "_intersec"
            )  # releasing, or lifting what it just took
            # kept: releasing, lifting what it just took, or going on to the grasp from a servoed
            # pre-grasp (the plan resumed, shifted, §5.3.1)
            blend = not servoed and not releasing and not at_contact and approach is None
            # A carry before a servoed placement that starts from a grasp's correction: that
            # correction moved the hand with the object where it lay, not the object in the hand
            # (after the grasp the object goes where the hand goes), so it blends out as after any
            # grasp, until the camera measures the object in the hand.
            blend_until_measured = (
                servoed
                and task.kind != "pbvs"
                and not holder
                and carried_anchor is not None
                and not at_contact
            )
            c = TaskCorrection(
                task.name,
                servoed,
                C0,
                blend or blend_until_measured,
                int(traj.duration * 1e6),
                start_utime,
                C0,
                [(start_utime, C0)],
                frame=task.frame,
                anchor=anchor,
                holder=holder,
                holder_end=self._planned_end(traj, holder) if holder else None,
                moved_utime=start_utime,
                C_start_measured=not C0.isIdentity() and not blend_until_measured,
            )
            corrections.append(c)
            handle = holds[task.name] if task.name in holds else approach
            if servoed and gripper is not None and handle is not None:
                obj = handle.split("/")[0]
                X_GO = self._planned_grasp(traj, holder or task.frame, obj)
                self._current.append((c, step, obj, X_GO, approach is not None))
                if approach is not None:
                    with self._lock:  # what the camera saw of it at rest comes first
                        self._pending.extend(
                            (u, obj, X, r, True) for u, X, r in self._at_rest.get(obj, [])
                        )
            self._carried[task.frame] = (pin.SE3.Identity(), None) if blend else c.carried(C0)
        return corrections

    def end_step(self, corrections: list[TaskCorrection]) -> None:
        for c in corrections:
            if c.servoed:
                # a ramp no measurement interrupted ended on the plan
                self._carried[c.frame] = (
                    (pin.SE3.Identity(), None) if c.blend_out else c.carried(c.C)
                )

    def _world_left(
        self, C: pin.SE3, anchor: pin.SE3 | None, traj: StepTrajectory, frame: str
    ) -> pin.SE3:
        """A carried correction as the world-frame left correction L it amounts to at this
        step's start: A C A^-1 when anchored, else P0 C P0^-1 (a right correction of the planned
        pose P0 of ``frame``)."""
        A = anchor if anchor is not None else self._planned_pose(traj, frame, 0)
        return A * C * A.inverse()

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
        """Folds the measurements received since the last call into the servoed corrections'
        targets (each moves ``alpha`` of the way to a measurement's fixed point: the average
        that filters the camera noise) and moves each correction towards its target within its
        speed limits for the time elapsed; True when a correction changed. An object no
        gripper touches in this step is at rest: its measurements are kept for the servoed
        approach to it (:meth:`begin_step` hands them over first)."""
        pending = self._take_pending()
        o = self.options
        changed = False
        for c, step, obj, X_GO, approach in self._current:
            values = planned[c.task][0]
            traj = self.trajectories[step.index] if approach else None
            for utime, name, X_WO, reproj, replayed in pending:
                if name != obj:
                    continue
                stale = utime < c.start_utime and not (approach and replayed)
                if reproj > o.max_reprojection_px or stale:
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
                    if c.holder:
                        X_WH = self._commanded_holder(c.holder, traj, k, utime)
                        if X_WH is None:
                            self.measurements_hand_off_command += 1
                            continue
                        C_star = handover_fixed_point(X_GO, X_WO, X_WH)
                    else:
                        C_star = approach_fixed_point(c.anchor, X_WO, X_WO_plan)
                else:
                    X_WH = self._commanded_hand(c, P, k, utime, dt_us)
                    if X_WH is None:
                        self.measurements_hand_off_command += 1
                        continue
                    C_star = correction_fixed_point(X_GO, X_WO, X_WH)
                if np.linalg.norm(C_star.translation) > o.max_correction:
                    self.measurements_rejected += 1
                    continue
                if c.blend_out:  # a ramp interrupted: the correction stays where it was streamed
                    k_now = (now_utime + o.lead_us - c.start_utime) // dt_us
                    c.C = c.at_sample(int(np.clip(k_now, 0, len(values) - 1)), dt_us)
                    c.blend_out, c.moved_utime = False, now_utime
                    c.history.append((now_utime, c.C))
                    c.version += 1
                # A correction that starts from nothing takes the running mean of its first
                # measurements (the first one's weight 1: not pulled towards the identity it knew
                # nothing about), then their exponential average (``alpha``); one carried from
                # the step before has the average of earlier measurements in it already.
                c.folded += 1
                weight = o.alpha if c.C_start_measured else max(o.alpha, 1.0 / c.folded)
                start = c.C if c.target is None else c.target
                c.target = step_toward(start, C_star, weight, math.inf, math.inf)
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
                        "at_rest": bool(replayed),
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
            changed |= self._move_towards_target(c, now_utime, approach)
        return changed

    def _commanded_hand(
        self, c: TaskCorrection, P: pin.SE3, k: int, utime: int, dt_us: int
    ) -> pin.SE3 | None:
        """The hand the controller commanded at ``utime`` (module doc), None when the encoders
        put the hand more than ``max_tracking_*`` from it or no state and command came then;
        without robot states at all (no robot map), the reference tracked then, P C(t_i)."""
        if self._states is None or not self._states.has_state():
            return P * (c.at_sample(k, dt_us) if c.blend_out else c.active_at(utime))
        poses = self._hand_poses(c.frame, utime)
        if poses is None:
            return None
        measured, commanded = poses
        err = commanded.actInv(measured)
        o = self.options
        if (
            float(np.linalg.norm(err.translation)) > o.max_tracking_m
            or float(np.linalg.norm(pin.log3(err.rotation))) > o.max_tracking_rad
        ):
            return None
        return commanded

    def _commanded_holder(
        self, frame: str, traj: StepTrajectory, k: int, utime: int
    ) -> pin.SE3 | None:
        """The holding gripper the controller commanded at ``utime``: what its relative tasks
        are computed on. Unlike a carry's (:meth:`_commanded_hand`) it is used however far the
        encoders put the hand from it: that distance (a wrist sagging at its torque limit) is what
        a hand-over must see. None when no state and command came then; without robot states
        at all (no robot map), the planned pose."""
        if self._states is None or not self._states.has_state():
            return self._planned_pose(traj, frame, min(k, len(traj.q) - 1))
        poses = self._hand_poses(frame, utime)
        return None if poses is None else poses[1]

    def _take_pending(self) -> list[tuple[int, str, pin.SE3, float, bool]]:
        """The measurements received since the last call; those of an object no gripper
        touches in this step are kept for an approach to it."""
        with self._lock:
            pending, self._pending = self._pending, []
            for utime, name, X_WO, reproj, replayed in pending:
                if (
                    not replayed
                    and name not in self._touched
                    and utime >= self._step_start
                    and reproj <= self.options.max_reprojection_px
                ):
                    kept = self._at_rest.setdefault(name, [])
                    kept.append((utime, X_WO, reproj))
                    del kept[: -self.AT_REST_KEPT]
        return pending

    def _move_towards_target(self, c: TaskCorrection, now_utime: int, approach: bool) -> bool:
        """C moved towards its target within the speed limits for the time since it last
        moved: the reference never jumps, however many measurements arrived at once. An
        approach's correction goes as fast as it must to arrive by ``approach_settle`` of the
        step, within ``max_approach_speed``."""
        if c.target is None or c.blend_out:
            return False
        dt = min(max(now_utime - c.moved_utime, 0), 200_000) * 1e-6
        o = self.options
        v, w = o.max_speed, o.max_angular_speed
        if approach:
            left = (c.start_utime + o.approach_settle * c.duration_us - now_utime) * 1e-6
            xi = pin.log6(c.C.actInv(c.target)).vector
            if left > 0:  # after that, what a late measurement asks for goes at the usual pace
                v = min(max(v, float(np.linalg.norm(xi[:3])) / left), o.max_approach_speed)
                w = min(max(w, float(np.linalg.norm(xi[3:])) / left), o.max_approach_angular_speed)
        C = step_toward(c.C, c.target, 1.0, v * dt, w * dt)
        c.moved_utime = now_utime
        if np.allclose(C.homogeneous, c.C.homogeneous, rtol=0.0, atol=1e-9):
            return False
        c.C = C
        c.history.append((now_utime, c.C))
        c.version += 1
        return True


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
    joints: tuple[str, ...],
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
    robot_map: PlanRobotMap,
    obj: str,
    camera_frame: str,
    head_joints: tuple[str, ...],
    lean: Lean | None = None,
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
        head_gaze_posture(robot_map.model, traj, targets, camera_frame, head_joints, ramp_in=first)

    return rewrite


def add_gaze(
    trajectories: dict[int, StepTrajectory],
    steps: list[Step],
    robot_map: PlanRobotMap,
    obj: str,
    camera_frame: str,
    head_joints: tuple[str, ...],
) -> None:
    """:func:`gaze_rewrite` applied to already sampled ``trajectories`` of ``steps`` (the first
    of them ramps the gaze in), without re-timing."""
    rewrite = gaze_rewrite(robot_map, obj, camera_frame, head_joints)
    for i, step in enumerate(steps):
        rewrite(step, trajectories[step.index], i == 0)
