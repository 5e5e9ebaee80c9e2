"""A tool held by an arm, moved by one streamed SE3 task (what the drill, thesis 000 §6.3, and the
deburring, §5.3.3, scenarios run on).

* geometry of a tool on a hole: the tool's x axis along the hole axis (the x axis of the hole's
  handle frame, ``mask: [1, 1, 1, 0, 1, 1]``: the rotation about it is free), its origin a
  standoff before the hole (:func:`tool_target`, :func:`tool_error`, :func:`axis_offset`);
* :class:`ToolTask`: the controller spec (tool SE3 task, posture below it), minimum-jerk moves
  streamed on TASK_REFERENCE, and corrections on a measured tool pose (:meth:`ToolTask.servo`).

Settings are duck-typed: any object with the attributes :class:`ToolTask` reads (the drill's and
the deburring scenario's settings dataclasses both have them).
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.control.client import ControllerClient, configuration_from_state, pose_to_vector
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.errors import ExecutionError
from marionette.execution.references import minimum_jerk
from marionette.execution.streamer import MAX_LOOKAHEAD_S, ReferenceStreamer

# ---- geometry --------------------------------------------------------------------------------


def axis_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle [deg] between two directions."""
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def tool_target(X_W_hole: pin.SE3, R_W_tool_now: np.ndarray, standoff: float) -> pin.SE3:
    """Tool pose on the hole: x axis along the hole axis (x of the handle), origin ``standoff``
    before it, and the rotation about the axis (masked in the task) kept from the current tool
    pose: the smallest rotation taking the current tool axis onto the hole's."""
    a = X_W_hole.rotation[:, 0]
    x = R_W_tool_now[:, 0]
    v = np.cross(x, a)
    s, c = np.linalg.norm(v), float(np.dot(x, a))
    R_align = np.eye(3) if s < 1e-12 else pin.exp3(v / s * np.arctan2(s, c))
    return pin.SE3(R_align @ R_W_tool_now, X_W_hole.translation - standoff * a)


def tool_error(X_W_tool: pin.SE3, X_W_target: pin.SE3) -> tuple[float, float]:
    """(position error [m], axis angle error [deg]) of the tool against a target tool pose;
    rotation about the tool axis is free (masked)."""
    return (
        float(np.linalg.norm(X_W_tool.translation - X_W_target.translation)),
        axis_angle_deg(X_W_tool.rotation[:, 0], X_W_target.rotation[:, 0]),
    )


def axis_offset(X_W_tool: pin.SE3, X_W_hole: pin.SE3) -> tuple[float, float, float]:
    """(distance [m] of the hole's centre from the tool axis, angle [deg] between the tool axis
    and the hole axis, standoff [m] of the tool origin before the hole along the hole axis): the
    deburring criterion "tool axis within 1 mm / 1 deg of the hole axis" is the first two."""
    a = X_W_tool.rotation[:, 0]
    d = X_W_hole.translation - X_W_tool.translation
    across = d - np.dot(d, a) * a
    return (
        float(np.linalg.norm(across)),
        axis_angle_deg(a, X_W_hole.rotation[:, 0]),
        float(np.dot(d, X_W_hole.rotation[:, 0])),
    )


def actuator_limits(scene: Path) -> dict[str, float]:
    """Joint name -> |force limit| of the scene's MJCF actuators (``forcerange``)."""
    return {
        n: max(abs(float(a)), abs(float(b)))
        for n, a, b in re.findall(
            r'<general name="([^"]+)"[^>]*forcerange="(\S+) (\S+)"', Path(scene).read_text()
        )
    }


# ---- the task --------------------------------------------------------------------------------


class ToolTask:
    """Tool pose from ROBOT_STATE (MuJoCo's joint positions) through the robot's kinematics, and
    the tool SE3 task's moves streamed on TASK_REFERENCE.

    ``frame``: the URDF frame the task drives; the tool frame is ``X_link_tool`` in ``tool_link``
    (a gripper's declaration), both on one joint; its x axis (the tool axis) must be ``frame``'s z
    axis: the rotation about it is masked.
    ``stream_posture``: the posture task below follows a streamed configuration as well
    (:meth:`move` with ``q``), else it holds the configuration the controller started with."""

    CONTROLLER_ID = 1

    def __init__(
        self,
        client: ControllerClient,
        settings,
        robot: str,
        frame: str,
        tool_link: str,
        X_link_tool: pin.SE3,
        scene: Path,
        name: str = "tool",
        stream_posture: bool = False,
    ) -> None:
        self.client, self.settings, self.scene, self.name = client, settings, Path(scene), name
        self.robot, self.frame = robot, frame
        self.model, _ = robots.load_pinocchio(robot, with_collision=False)
        self.data = self.model.createData()
        for f in (frame, tool_link):
            if not self.model.existFrame(f):
                raise ExecutionError(f"{robot} has no frame {f} for the tool task")
        self.fid = self.model.getFrameId(frame)
        X_frame_link = self.model.frames[self.fid].placement.actInv(
            self.model.frames[self.model.getFrameId(tool_link)].placement
        )
        self.X_frame_tool = X_frame_link * X_link_tool
        self.stream_posture = stream_posture
        self.reference: pin.SE3 | None = None  # last frame reference streamed
        self.posture: np.ndarray | None = None  # last posture reference streamed

    def spec(self) -> ControllerSpec:
        """Tool pose task (rotation about the tool axis = the frame's z masked), posture below."""
        return ControllerSpec(
            self.CONTROLLER_ID,
            self.name,
            [
                TaskSpec(
                    "tool",
                    "se3",
                    0,
                    frame=self.frame,
                    mask=(True, True, True, True, True, False),
                    gain=10.0,
                    streamed=True,
                ),
                TaskSpec("posture", "posture", 1, gain=1.0, streamed=self.stream_posture),
            ],
            reference_timeout=0.2,
        )

    def configuration(self, state=None) -> np.ndarray:
        """The robot's configuration (controller layout) from ``state`` (default the latest)."""
        return configuration_from_state(
            self.model, state if state is not None else self.client.state
        )

    def frame_of(self, q: np.ndarray) -> pin.SE3:
        """Pose X_W_frame of the task's frame at configuration ``q``."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.fid]

    def tool_of(self, q: np.ndarray) -> pin.SE3:
        """Tool pose X_W_tool at configuration ``q`` (nominal kinematics)."""
        return self.frame_of(q) * self.X_frame_tool

    def pose(self, state=None) -> pin.SE3:
        """Tool pose X_W_tool from ``state`` (default the latest ROBOT_STATE)."""
        return self.tool_of(self.configuration(state))

    def move(self, X_W_tool: pin.SE3, duration_s: float, q: np.ndarray | None = None) -> None:
        """Minimum-jerk geodesic of the frame's reference from the last reference sent to
        ``X_W_tool`` (and, with a streamed posture, of the posture to ``q``, default the last
        one); returns when the last sample's time has passed plus ``settle_s``."""
        X1 = X_W_tool * self.X_frame_tool.inverse()
        self.move_along([X1], duration_s, None if q is None else [q])

    def move_along(
        self,
        frames: Sequence[pin.SE3],
        duration_s: float,
        postures: Sequence[np.ndarray] | None = None,
    ) -> None:
        """Like :meth:`move` through the frame references ``frames`` (and postures): one
        minimum-jerk time law over the polyline of both, its knots equally spaced in time."""
        st = self.settings
        X0 = (
            self.reference
            if self.reference is not None
            else self.pose() * self.X_frame_tool.inverse()
        )
        Xs = [X0, *frames]
        xis = [pin.log6(a.actInv(b)).vector for a, b in zip(Xs, Xs[1:])]
        # at least the duration that keeps the mean speed under the limits (the drill's first
        # move turns the spindle from vertical to horizontal: a wrist joint swept 2.3 rad in 1 s,
        # its actuator saturated (54 N.m) and the wrist ended 0.23 rad past its command, stuck)
        duration_s = max(
            duration_s,
            sum(np.linalg.norm(x[:3]) for x in xis) / st.max_tool_speed,
            sum(np.linalg.norm(x[3:]) for x in xis) / st.max_tool_rate,
        )
        n = len(xis)
        s, ds = minimum_jerk(np.zeros(1), np.array([float(n)]), duration_s, 0.001)
        u, du = s[:, 0], ds[:, 0]
        k = np.minimum(u.astype(int), n - 1)
        frac = u - k
        tool = np.empty((len(u), 7))
        vel = np.empty((len(u), 6))
        for i in range(len(u)):
            Xi = Xs[k[i]] * pin.exp6(frac[i] * xis[k[i]])
            tool[i] = pose_to_vector(Xi)
            vel[i] = du[i] * xis[k[i]]  # d/dt of the log coordinates (the drill's stream)
        streams = {"tool": (tool, vel)}
        if self.stream_posture:
            q0 = self.posture if self.posture is not None else self.configuration()
            qs = [q0, *(postures if postures is not None else [q0] * n)]
            if len(qs) != n + 1:
                raise ValueError("one posture per frame reference")
            dq = [pin.difference(self.model, a, b) for a, b in zip(qs, qs[1:])]
            values = np.array(
                [pin.integrate(self.model, qs[k[i]], frac[i] * dq[k[i]]) for i in range(len(u))]
            )
            streams["posture"] = (values, np.array([du[i] * dq[k[i]] for i in range(len(u))]))
            self.posture = qs[-1]
        self._stream(streams, duration_s)
        self.reference = Xs[-1]

    def follow(
        self,
        q_path: Sequence[np.ndarray],
        duration_s: float,
        correction: pin.SE3 | None = None,
        max_step_rad: float = 0.05,
    ) -> None:
        """Moves along a joint path (a planned one): the streamed posture follows it and the
        frame reference follows its forward kinematics, left-multiplied by ``correction`` (a
        world-frame map from the kinematics to the reference, e.g. the one a servo found). The
        knots are at most ``max_step_rad`` apart in every joint so that both tasks agree between
        them: with the frame on the SE3 geodesic between far-apart configurations and the posture
        on the straight joint line, the frame task (above) wins and the arm takes another branch
        (a TIAGo wrist flipped on its way to the first pre-grasp, 3 rad off the planned posture)."""
        if not self.stream_posture:
            raise ValueError("follow needs a streamed posture (stream_posture=True)")
        C = correction if correction is not None else pin.SE3.Identity()
        q0 = self.posture if self.posture is not None else self.configuration()
        knots = []
        for a, b in zip([q0, *q_path], q_path):
            d = pin.difference(self.model, a, b)
            n = max(1, int(np.ceil(np.max(np.abs(d), initial=0.0) / max_step_rad)))
            knots += [pin.integrate(self.model, a, d * (i / n)) for i in range(1, n + 1)]
        self.move_along([C * self.frame_of(q) for q in knots], duration_s, postures=knots)

    # The stream starts this far after the controller's latest time, and is sent this far ahead
    # (the most the controller keeps). A loaded machine (a demo, a trial beside it and a build on
    # 2 cores) stopped this process for 0.3 s between reading the time and the first chunk (with
    # 30 ms of lead the chunk arrived already past), and once for 2 s between two chunks (with 1 s
    # of look-ahead the stream ran dry): both times the controller's watchdog held the robot.
    START_LEAD_S = 0.5
    LOOKAHEAD_S = MAX_LOOKAHEAD_S

    def _stream(self, streams: dict, duration_s: float) -> None:
        st = self.settings
        start = self.client.utime() + int(self.START_LEAD_S * 1e6)
        streamer = ReferenceStreamer(
            self.client.send_reference,
            self.CONTROLLER_ID,
            streams,
            start,
            lookahead_s=self.LOOKAHEAD_S,
        )
        while not streamer.done:
            streamer.pump(self.client.utime())
            time.sleep(0.005)
        end = streamer.end_utime + int(st.settle_s * 1e6)
        self.client.wait(
            lambda c: c.state.utime >= end, 10.0 + 10.0 * duration_s, "the end of a tool move"
        )
        # The MuJoCo joint servos ring for a while after a move in some postures: measuring a
        # moving arm makes the next correction chase it. Wait until it is still (or give up
        # after settle_timeout_s of controller time and let the correction loop judge).
        give_up = end + int(st.settle_timeout_s * 1e6)
        self.client.wait(
            lambda c: (
                c.state.utime >= give_up
                or max(abs(v) for v in c.state.joint_velocity) < st.still_velocity
            ),
            10.0 + 10.0 * st.settle_timeout_s,
            "the arm to be still",
        )

    def reference_tool(self) -> pin.SE3:
        """The tool pose the controller was last asked for."""
        return self.reference * self.X_frame_tool

    def servo(
        self,
        target: Callable[[pin.SE3], pin.SE3],
        measure: Callable[[], pin.SE3] | None = None,
        aligned: tuple[float, float] | None = None,
    ) -> tuple[pin.SE3, int, bool]:
        """Corrects the tool until ``target(measured tool pose)`` is within ``aligned`` ([m],
        [deg]; default the settings' ``aligned_m``, ``aligned_deg``) of it; returns the final
        measured tool pose, the number of corrections and whether it got there within
        ``max_corrections``.

        ``measure`` gives the tool pose (default :meth:`pose`: the joint encoders, i.e. MuJoCo's
        joints). It differs from the reference the controller tracks (the arm's sag under
        gravity in the joint servos; a tool held off its nominal pose), so a correction moves the
        *reference* by the measured error, X_ref <- (X_t X^-1) X_ref (an integral action on the
        pose: exact when the offset does not change with the small correction), rather than
        sending X_t again."""
        st = self.settings
        measure = measure or self.pose
        aligned_m, aligned_deg = aligned or (st.aligned_m, st.aligned_deg)
        for k in range(st.max_corrections + 1):
            if self.client.status.mode != "running":
                raise ExecutionError(
                    f"the controller stopped tracking the tool: {self.client.status.mode} "
                    f"({self.client.status.mode_reason})"
                )
            X = measure()
            X_t = target(X)
            dp, da = tool_error(X, X_t)
            if dp < aligned_m and da < aligned_deg:
                return X, k, True
            if k == st.max_corrections:
                return X, k, False
            X_ref = (X_t * X.inverse()) * self.reference_tool()
            if tool_error(X_ref, X_t)[0] > st.max_reference_offset_m:
                # anti-windup: the sag is a few mm; a reference pushed farther than this means
                # the arm cannot hold the pose (actuators at their torque limits)
                return X, k, False
            self.move(X_ref, st.correction_duration_s)
        raise AssertionError("unreachable")

    def saturated_joints(self) -> list[str]:
        """Joints whose actuator effort is within 1 % of its MJCF ``forcerange``."""
        limits = actuator_limits(self.scene)
        s = self.client.state
        return [
            f"{n} {e:.0f} N.m"
            for n, e in zip(s.joint_name, s.joint_effort)
            if n in limits and abs(e) >= 0.99 * limits[n]
        ]
