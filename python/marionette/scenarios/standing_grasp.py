"""A standing humanoid grasps an object by friction and lifts it (the end of ``grasp-walk``,
Dang 2012 ch. 6): balance held, the hand brought over the object, lowered onto it, the fingers
closed by the gripper admittance until they squeeze it (thesis 000 §3.2.4.3), then lifted.

Two stacks, both with the feet, the CoM and the waist's orientation held where they are at
level 0 and the posture at level 2:

* **approach** (:func:`approach_spec`): the gripper's base link follows a streamed pose at level
  1 — up to a clearing point above and short of the pre-grasp, over to the pre-grasp
  (``approach_distance`` back from the grasp along the approach axis), then down that axis onto
  the object; the fingers stay open (the posture holds them);
* **grip** (:func:`grip_spec`): the same with a ``gripper_admittance`` task on the gripper's joint
  at level 1 (close, then hold ``force_target``) and the posture without that joint; the hand
  holds where the approach left it, then follows the lift.

The grasp's orientation (:func:`grasp_pose`): the gripper frame's x (the approach axis, HPP's
convention) points down, tilted by ``approach_tilt_deg`` away from the shoulder; its y (the
closing axis, robot.yaml ``jaws``) is horizontal. A ball has no preferred orientation: the sign
of y is the one nearer the hand's current orientation.

What the robot senses decides whether it holds the object (:func:`grasp_check`, the gripper's
encoder): fingers that closed to within ``empty_margin`` of the stroke from the closed position
met nothing; fingers that stopped more than ``width_margin`` of the stroke from where the
object's width stops them (the jaws' geometry, :meth:`marionette.models.jaw.Linkage.
position_for_width`) hold something else. Either way the robot does not lift. The simulator's
truth (SIM_OBJECT_POSES) only judges afterwards: how high the object rose, how it moved in the
hand (:class:`GripForceRecorder`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.control.client import ControllerClient, configuration_from_state
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.factory import (
    ADMITTANCE,
    GAINS,
    GripperJoint,
    gripper_joint,
    gripper_linkage,
)
from marionette.execution.grip_force import GripForceRecorder, GripperGeometry
from marionette.execution.references import grip_ramp_s, minimum_jerk
from marionette.execution.streamer import stream_to_end
from marionette.execution.walking import walking_spec

HELD = ("left_foot", "right_foot", "com", "waist")  # the walking stack's balance tasks


@dataclass(frozen=True)
class GraspSettings:
    """How the hand takes the object and how far it lifts it."""

    approach_distance: float = 0.10  # [m] pre-grasp: back from the grasp along the approach axis
    # [m] the hand first rises to the pre-grasp's height this far short of it (toward the
    # shoulder) and that much higher: a straight line from a hanging hand to the pre-grasp sweeps
    # the fingers through the object (a ball knocked 2.5 m away, measured)
    clear_back: float = 0.15
    clear_up: float = 0.05
    approach_tilt_deg: float = 20.0  # approach axis from the vertical, away from the shoulder
    to_pregrasp_s: float = 3.0  # [s] minimum-jerk motions of the hand
    descend_s: float = 2.0
    lift: float = 0.10  # [m] the hand rises this much with the object
    lift_s: float = 2.0
    hold_s: float = 1.0  # [s] held up before the verdict
    min_lift: float = 0.05  # [m] the object's rise that counts as lifted
    empty_margin: float = 0.1  # fraction of the stroke from closed: the fingers met nothing
    # fraction of the stroke between where the fingers stop and where the object's width stops
    # them (jaw geometry) beyond which they hold something else: the 50 mm ball stops TALOS'
    # fingers at -0.336 to -0.354 rad for -0.345 predicted; closing on the tee, at -0.62
    width_margin: float = 0.1
    # [m] the fingers close only with the grasp point (from the encoders) this near its target:
    # 4.6-5.9 mm over 20 trials; a hand stopped short (an object beyond reach) closes on nothing
    reach_tolerance: float = 0.015


def arm_reach(model: pin.Model, hand: str) -> tuple[float, str]:
    """Reach [m] of the ``hand`` arm: shoulder (``arm_<hand>_1`` joint) to grasp point with the
    arm stretched (arm joints at zero: TALOS' arm hangs straight), and the shoulder frame. (The
    grasp point's frame is the walking model's, :func:`footsteps.robot_model.walking_robot`.)"""
    q = pin.neutral(model)
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    shoulder = f"arm_{hand}_1_link"
    grasp = f"{hand}_grasp_point"
    d = np.linalg.norm(
        data.oMf[model.getFrameId(grasp)].translation
        - data.oMf[model.getFrameId(shoulder)].translation
    )
    return float(d), shoulder


def grasp_pose(
    p_object: np.ndarray, shoulder: np.ndarray, tilt_deg: float, R_now: np.ndarray
) -> pin.SE3:
    """The gripper frame's target (module docstring) with its origin on ``p_object``: x down,
    tilted ``tilt_deg`` away from ``shoulder`` (horizontally), y horizontal with the sign nearer
    the current rotation ``R_now``."""
    ez = np.array([0.0, 0.0, 1.0])
    u = np.array([*(p_object - shoulder)[:2], 0.0])
    u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-6 else np.array([1.0, 0.0, 0.0])
    t = np.radians(tilt_deg)
    x = -np.cos(t) * ez + np.sin(t) * u
    best = None
    for sign in (1.0, -1.0):
        y = sign * np.cross(ez, u)
        R = np.column_stack([x, y, np.cross(x, y)])
        angle = float(np.linalg.norm(pin.log3(R_now.T @ R)))
        if best is None or angle < best[0]:
            best = (angle, R)
    assert best is not None
    return pin.SE3(best[1], np.asarray(p_object, dtype=float))


def pose_minimum_jerk(
    X0: pin.SE3, X1: pin.SE3, duration_s: float, dt_s: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """A pose moving from ``X0`` to ``X1`` on the minimum-jerk time law (:func:`minimum_jerk`):
    the origin along the segment, the rotation R0 exp(s w) about one axis (w = log(R0ᵀ R1));
    rows (x y z qw qx qy qz) and derivatives (v, ω in world axes) for an se3 task."""
    p, dp = minimum_jerk(X0.translation, X1.translation, duration_s, dt_s)
    w = pin.log3(X0.rotation.T @ X1.rotation)
    s, ds = minimum_jerk(np.zeros(1), np.ones(1), duration_s, dt_s)
    values = np.empty((len(p), 7))
    for k in range(len(p)):
        q = pin.Quaternion(X0.rotation @ pin.exp3(s[k, 0] * w))
        values[k] = [*p[k], q.w, q.x, q.y, q.z]
    derivatives = np.hstack([dp, ds * (X0.rotation @ w)[None, :]])
    return values, derivatives


def _balance_and_posture(robot: str, posture_joints: list[str]) -> tuple[list[TaskSpec], TaskSpec]:
    """The walking stack's balance tasks, each holding its value at the swap's tick, and its
    posture (level 2) over ``posture_joints`` (empty: every 1-DoF joint). Holding the walk's
    references instead would keep its base motion toward soles that landed a few mm off, which the
    hand task turns into arm motion (0.07-0.29 rad/s measured after 6-8 steps)."""
    walk = {t.name: t for t in walking_spec(robot, 1).tasks}
    held = [dataclasses.replace(walk[n], reference_channel="", reference=()) for n in HELD]
    posture = dataclasses.replace(walk["posture"], priority=2, joints=tuple(posture_joints))
    return held, posture


def hand_task(frame: str) -> TaskSpec:
    return TaskSpec("hand", "se3", 1, frame=frame, gain=GAINS["grasp"], streamed=True)


def approach_spec(controller_id: int, robot: str, frame: str) -> ControllerSpec:
    """Balance at level 0, the hand (``frame``) streamed at level 1, posture at level 2."""
    held, posture = _balance_and_posture(robot, [])
    return ControllerSpec(controller_id, "approach", tasks=[*held, hand_task(frame), posture])


def grip_spec(
    controller_id: int, robot: str, frame: str, joint: GripperJoint, model: pin.Model
) -> ControllerSpec:
    """:func:`approach_spec` with the gripper admittance closing ``joint`` at level 1 and the
    posture without that joint (it would pull the fingers back open)."""
    others = [
        model.names[j]
        for j in range(1, model.njoints)
        if model.joints[j].nv == 1 and model.names[j] != joint.joint
    ]
    held, posture = _balance_and_posture(robot, others)
    admittance = TaskSpec(
        "gripper_admittance",
        "gripper_admittance",
        1,
        gain=GAINS["gripper"],
        reference=(joint.closed_position,),
        joints=(joint.joint,),
        parameters=dict(ADMITTANCE, **joint.parameters, closing_direction=joint.closing_direction),
    )
    return ControllerSpec(
        controller_id, "grip", tasks=[*held, hand_task(frame), admittance, posture]
    )


def grasp_check(
    joint: GripperJoint,
    position: float,
    empty_margin: float,
    expected: float | None = None,
    width_margin: float = 0.1,
) -> str | None:
    """None when the fingers stopped on the object; else why the hand does not hold it: the
    fingers reached their closed stop (within ``empty_margin`` of the stroke: nothing between
    them), or they stopped more than ``width_margin`` of the stroke away from ``expected``, where
    an object of the grasped one's width stops them (something else between them)."""
    closure = joint.closure(position)
    if closure >= 1.0 - empty_margin:
        return (
            f"grasp missed: the fingers closed to {position:.3f} ({closure:.0%} of their "
            f"stroke, closed at {joint.closed_position:g}): nothing between them"
        )
    if expected is not None and abs(closure - joint.closure(expected)) > width_margin:
        return (
            f"grasp missed: the fingers stopped at {position:.3f} where the object stops them at "
            f"{expected:.3f} ({abs(closure - joint.closure(expected)):.0%} of their stroke "
            f"apart): what they hold is not the object"
        )
    return None


class StandingGrasp:
    """One grasp and lift by ``robot``'s ``hand`` (the module's sequence). ``client``: the
    controller, standing; ``model``: its Pinocchio model (frames of robot.yaml's links)."""

    def __init__(
        self,
        client: ControllerClient,
        model: pin.Model,
        robot: str,
        hand: str,
        settings: GraspSettings,
        log: Callable[[str], None] = print,
    ) -> None:
        self.client, self.model, self.robot, self.hand = client, model, robot, hand
        self.settings, self.log = settings, log
        desc = robots.robot(robot)
        self.gripper = robots.semantics(robot).gripper(desc.walking["hands"][hand])
        self.joint = gripper_joint(self.gripper, model, robot)
        self.frame = self.gripper.link
        self.X_link_gripper = self.gripper.pose.se3()
        self.data = model.createData()
        geometry = GripperGeometry.of(
            robot, self.gripper.name, self.joint.parameters, self.joint.closing_direction
        )
        self.recorder = (
            GripForceRecorder(model, {self.gripper.name: geometry}).subscribe(client.bus)
            if geometry is not None
            else None
        )
        self.reach, self.shoulder_frame = arm_reach(model, hand)
        self.chunks = 0
        self.lookahead_ms: list[float] = []

    # -- measures --------------------------------------------------------------------------
    def _frame(self, name: str) -> pin.SE3:
        q = configuration_from_state(self.model, self.client.state)
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.model.getFrameId(name)].copy()

    def _finger(self) -> float:
        return float(self.client.joint_positions()[self.joint.joint])

    def _refuse(self, out: dict[str, Any], reason: str, then: str = "") -> dict[str, Any]:
        """The grasp stops for ``reason``: logged (with ``then``, what the robot does) and
        returned with the measures so far."""
        self.log(f"grasp: {reason}{then}")
        return {**out, "done": False, "lifted": False, "reason": reason}

    # -- motions ---------------------------------------------------------------------------
    def _swap(self, spec: ControllerSpec) -> str | None:
        """Sends ``spec``; None once the controller runs it, else the refusal."""
        cid, tag = spec.controller_id, f"(id {spec.controller_id})"
        self.client.send_spec(spec)
        try:
            self.client.wait(
                lambda c: (
                    c.status.active_controller_id == cid
                    or tag in c.status.last_switch_result
                    or tag in c.status.last_rejection
                ),
                10.0,
                f"the swap to the {spec.name} controller",
            )
        except TimeoutError as e:
            return str(e)
        st = self.client.status
        if st.active_controller_id == cid:
            return None
        return st.last_switch_result if tag in st.last_switch_result else st.last_rejection

    def _move(self, cid: int, X0: pin.SE3, X1: pin.SE3, duration_s: float) -> None:
        """Streams the gripper link from ``X0`` to ``X1`` and waits until the motion ended."""
        streamer = stream_to_end(self.client, cid, {"hand": pose_minimum_jerk(X0, X1, duration_s)})
        self.chunks += streamer.chunks_sent
        if streamer.min_margin_us is not None:
            self.lookahead_ms.append(streamer.min_margin_us / 1e3)

    def run(
        self, p_object: np.ndarray, width: float, object_name: str, plot_dir: Path
    ) -> dict[str, Any]:
        """Grasps the object ``width`` wide [m] whose centre the robot believes at ``p_object``
        (world) and lifts it; ``object_name`` names it in SIM_OBJECT_POSES for the verdict.
        Returns the measures (``lifted`` the verdict); the grip force's plot goes to
        ``plot_dir``."""
        s, client = self.settings, self.client
        out: dict[str, Any] = {"object_believed_at": [float(v) for v in p_object]}
        linkage = gripper_linkage(self.robot, self.gripper.name)
        expected = (
            None
            if linkage is None
            else linkage.position_for_width(
                width, self.joint.closed_position, self.joint.open_position
            )
        )
        out["finger_expected"] = expected
        X_link = self._frame(self.frame)
        shoulder = self._frame(self.shoulder_frame).translation
        distance = float(np.linalg.norm(np.asarray(p_object) - shoulder))
        out["object_to_shoulder_m"], out["arm_reach_m"] = distance, self.reach
        if distance > self.reach:
            return self._refuse(
                out,
                f"the {object_name} is {distance:.2f} m from the {self.hand} shoulder, beyond the "
                f"arm's reach ({self.reach:.2f} m): the robot does not reach for it (it needs "
                "another stance)",
            )
        X_grasp = grasp_pose(
            p_object, shoulder, s.approach_tilt_deg, (X_link * self.X_link_gripper).rotation
        )
        X_pre = X_grasp * pin.SE3(np.eye(3), np.array([-s.approach_distance, 0.0, 0.0]))
        inverse = self.X_link_gripper.inverse()
        link_pre, link_grasp = X_pre * inverse, X_grasp * inverse
        p_rest = client.object_pose(object_name).translation.copy()
        if (refused := self._swap(approach_spec(2, self.robot, self.frame))) is not None:
            return {**out, "done": False, "lifted": False, "reason": refused}
        back = np.array([*(p_object - shoulder)[:2], 0.0])
        back *= -s.clear_back / max(float(np.linalg.norm(back)), 1e-9)
        link_clear = pin.SE3(link_pre.rotation, link_pre.translation + back + [0, 0, s.clear_up])
        self._move(2, X_link, link_clear, s.to_pregrasp_s)
        self._move(2, link_clear, link_pre, s.descend_s)
        self._move(2, link_pre, link_grasp, s.descend_s)
        client.wait_time(0.5)
        X_at = self._frame(self.frame) * self.X_link_gripper
        out["grasp_point_error_m"] = float(np.linalg.norm(X_at.translation - X_grasp.translation))
        out["grasp_point_to_object_m"] = float(
            np.linalg.norm(X_at.translation - client.object_pose(object_name).translation)
        )
        if out["grasp_point_error_m"] > s.reach_tolerance:
            return self._refuse(
                out,
                f"the hand stopped {out['grasp_point_error_m'] * 1e3:.1f} mm from the grasp (more "
                f"than {s.reach_tolerance * 1e3:.0f} mm): the fingers do not close on what the "
                "hand did not reach; the robot holds where it is",
            )
        self.log(
            f"grasp: hand on the object, grasp point {out['grasp_point_error_m'] * 1e3:.1f} mm "
            f"from its target; closing"
        )
        if (
            refused := self._swap(grip_spec(3, self.robot, self.frame, self.joint, self.model))
        ) is not None:
            return {**out, "done": False, "lifted": False, "reason": refused}
        t_close = client.utime() * 1e-6
        stroke = abs(self.joint.closed_position - self.joint.open_position)
        client.wait_time(grip_ramp_s(stroke, {**ADMITTANCE, **self.joint.parameters}) + 1.0)
        finger = self._finger()
        out["finger_after_closing"] = finger
        missed = grasp_check(self.joint, finger, s.empty_margin, expected, s.width_margin)
        if missed is not None:
            return self._refuse(out, missed, "; the robot holds where it is")
        X_link = self._frame(self.frame)
        t_lift = client.utime() * 1e-6
        self._move(
            3, X_link, pin.SE3(X_link.rotation, X_link.translation + [0, 0, s.lift]), s.lift_s
        )
        client.wait_time(s.hold_s)
        t_end = client.utime() * 1e-6
        p_end = client.object_pose(object_name).translation
        rise = float(p_end[2] - p_rest[2])
        finger = self._finger()
        missed = grasp_check(self.joint, finger, s.empty_margin, expected, s.width_margin)
        out.update(
            done=True,
            object_rise_m=rise,
            hand_lift_m=s.lift,
            finger_after_lift=finger,
            lost_during_lift=missed,
            lifted=bool(rise >= s.min_lift and missed is None),
            t_close_s=t_close,
            t_lift_s=t_lift,
            t_end_s=t_end,
            chunks=self.chunks,
            min_lookahead_ms=min(self.lookahead_ms) if self.lookahead_ms else None,
        )
        if self.recorder is not None:
            self.recorder.compute()
            out["holding"] = self.recorder.holding_summary(
                self.gripper.name, t_lift, t_end, ADMITTANCE["force_target"]
            )
            motion = self.recorder.hold_motion(self.gripper.name, object_name, t_lift, t_end)
            out["motion_in_hand_m_rad"] = None if motion is None else list(motion)
            if self.recorder.t:
                self.recorder.plot(
                    plot_dir / "grip_force.png",
                    ADMITTANCE["force_target"],
                    {self.gripper.name: [(t_close, t_end)]},
                )
        self.log(
            f"grasp: object {'lifted' if out['lifted'] else 'NOT lifted'} by "
            f"{rise * 1e3:.0f} mm (hand {s.lift * 1e3:.0f} mm)"
        )
        return out
