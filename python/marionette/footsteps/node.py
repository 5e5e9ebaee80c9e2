"""The footstep process: OBJECT_POSES and WALK_STATUS in, FOOTSTEP_PLAN out (Dang Algorithm 4).

:class:`FootstepNode` holds the logic and no transport: feed it decoded messages, call
:meth:`FootstepNode.update` and publish what it returns. :func:`run` wires it to LCM.

Step indices are global and stable: step i of the first plan keeps index i in every replan, and
WALK_STATUS.current_step_index refers to them. A replan freezes the steps that have started
(indices ≤ current_step_index, Algorithm 2 line 11) and publishes the others, with
``first_step_index`` = current_step_index + 1: the footstep manager replaces its steps from that
index on and never touches the step in progress.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from marionette.footsteps.augmented_robot import Stance, wrap_angle
from marionette.footsteps.errors import FootstepError
from marionette.footsteps.obstacles import Bar
from marionette.footsteps.plan import FootstepPlan

if TYPE_CHECKING:  # imported where used: they load Pinocchio
    from marionette.footsteps.planner import GraspPlanner
    from marionette.footsteps.robot_model import RobotDescription
    from marionette.footsteps.step_over import StepOverPlanner


def yaw_from_quaternion(wxyz) -> float:
    """Yaw of the x axis of a rotation given as a (w, x, y, z) quaternion [rad]."""
    w, x, y, z = (float(v) for v in wxyz)
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def rotate(wxyz, v) -> np.ndarray:
    """``v`` rotated by the (w, x, y, z) quaternion (normalised here)."""
    q = np.asarray(wxyz, dtype=float)
    w, u = q[0], q[1:]
    n = float(np.dot(q, q))
    v = np.asarray(v, dtype=float)
    return ((w * w - u @ u) * v + 2.0 * (u @ v) * u + 2.0 * w * np.cross(u, v)) / n


@dataclass
class NodeOptions:
    robot: str = ""  # a robot with two feet (robot.yaml); "" = the only such robot found
    mode: str = "grasp"  # "grasp" | "step-over"
    target: str = "ball"  # object whose pose is the hand/gaze target (grasp)
    # [m] the point the hand reaches, in the target's frame (a ball resting on a tracked support)
    target_point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    hand: str = "right"
    posture_frozen: bool = True  # replanning mode (Dang §6.2.2)
    bar: str = "bar"  # object name of the bar (step-over)
    bar_axis_yaw: float = 0.0  # [rad] the bar's axis in its object frame (pi/2: along its y)
    bar_radius: float = 0.02
    bar_length: float = 2.0
    goal: tuple[float, float, float] = (2.0, 0.0, 0.0)  # final stance (step-over)
    move_threshold: float = 0.002  # [m] object displacement that triggers a replan
    swing_margin: float = 0.03  # [m] eq. 5.1 clearance of the crossing swings (step-over)
    crossing_duration: float | None = None  # [s] of the crossing swings (None: the planner's)


def resolve_walking_robot(name: str) -> str:
    """``name``, or when empty the only robot with two feet found (FootstepError otherwise)."""
    from marionette import robots

    if name:
        return name
    walkers = [n for n in robots.robot_names() if len(robots.robot(n).feet) == 2]
    if len(walkers) != 1:
        raise FootstepError(
            "give the walking robot with --robot (robots with two feet: "
            f"{', '.join(walkers) or 'none'})"
        )
    return walkers[0]


class FootstepNode:
    """Algorithm 4 on messages: replan when the target moves or the step counter advances."""

    def __init__(
        self,
        options: NodeOptions,
        stance: Stance | None = None,
        robot: RobotDescription | None = None,
    ) -> None:
        if options.mode not in ("grasp", "step-over"):
            raise FootstepError(f"mode must be 'grasp' or 'step-over', got {options.mode!r}")
        if not np.isfinite(options.bar_axis_yaw):
            raise FootstepError(f"the bar's axis yaw must be finite, got {options.bar_axis_yaw}")
        self.options = options
        self.stance = stance
        self._robot = robot
        self.planner: GraspPlanner | StepOverPlanner | None = None
        self.plan_id = 0
        self.current_step = -1
        self.object_pose: np.ndarray | None = None  # (x, y, z, yaw) of target or bar
        self._planned_pose: np.ndarray | None = None
        self._planned_step = -1
        self.last_plan: FootstepPlan | None = None
        self.last_solve_ms = 0.0
        self._lock = threading.Lock()

    # -- inputs ----------------------------------------------------------------------------
    def on_object_poses(self, msg) -> None:
        name = self.options.target if self.options.mode == "grasp" else self.options.bar
        for obj in msg.objects:
            if obj.object_name == name:
                p = np.array(obj.position_world, dtype=float)
                if self.options.mode == "grasp" and any(self.options.target_point):
                    p = p + rotate(obj.quaternion_world, self.options.target_point)
                if np.all(np.isfinite(p)):
                    yaw = yaw_from_quaternion(obj.quaternion_world)
                    with self._lock:
                        if self.options.mode == "step-over":
                            yaw = self._bar_axis_yaw(yaw)
                        self.object_pose = np.array([p[0], p[1], p[2], yaw])

    def _bar_axis_yaw(self, frame_yaw: float) -> float:
        """The bar's axis yaw from its frame's: an axis has no sign, so of the two directions
        the one nearest the last estimate (the planner's frame of the bar stays the same)."""
        yaw = float(wrap_angle(frame_yaw + self.options.bar_axis_yaw))
        if self.object_pose is None:
            return yaw
        last = float(self.object_pose[3])
        return last + float(wrap_angle(2.0 * (yaw - last))) / 2.0

    def on_walk_status(self, msg) -> None:
        with self._lock:
            # Monotonic once a plan is out: a robot back to "standing" (-1) after the last step
            # has still executed the steps before it, which must never be replanned.
            index = int(msg.current_step_index)
            self.current_step = max(self.current_step, index) if self.planner else index
            if self.stance is None and self.planner is None and msg.current_step_index < 0:
                left, right = (
                    np.array(msg.left_foot, dtype=float),
                    np.array(msg.right_foot, dtype=float),
                )
                self.stance = Stance(left[[0, 1, 3]], right[[0, 1, 3]], float(left[2]))

    # -- Algorithm 4 -----------------------------------------------------------------------
    def update(self, utime: int):
        """Replan if needed; returns an lcmt_footstep_plan to publish, or None."""
        with self._lock:
            pose = None if self.object_pose is None else self.object_pose.copy()
            step = self.current_step
            stance = self.stance
        if pose is None or stance is None:
            return None
        start = time.perf_counter()
        planner = self.planner
        if planner is None:
            planner = self.planner = self._initial_plan(stance, pose)
        else:
            planned = self._planned_pose
            moved = (
                planned is None
                or np.linalg.norm(pose[:2] - planned[:2]) > self.options.move_threshold
                or abs(pose[3] - planned[3]) > self.options.move_threshold
            )
            if not moved and step == self._planned_step:
                return None
            if self.last_plan is not None and step >= len(self.last_plan.steps) - 1:
                return None  # walking done: nothing left to change
            if not moved and self.last_plan is not None and step + 2 >= len(self.last_plan.steps):
                # Only the last step is still to start and it belongs to the frozen posture: with
                # the target where it was planned, a replan could only append two in-place steps
                # (the planner's answer to a moved target) and the walk would never end.
                return None
            self._replan(planner, pose, executed=step + 1)
        self.last_solve_ms = 1e3 * (time.perf_counter() - start)
        self._planned_pose, self._planned_step = pose, step
        self.last_plan = planner.result()
        self.plan_id += 1
        return self.last_plan.to_lcm(utime, self.plan_id, first_step_index=max(step + 1, 0))

    def robot(self) -> RobotDescription:
        """The walking robot (its description, loaded once)."""
        if self._robot is None:
            from marionette.footsteps.robot_model import walking_robot

            self._robot = walking_robot(resolve_walking_robot(self.options.robot))
        return self._robot

    def _initial_plan(self, stance: Stance, pose: np.ndarray) -> GraspPlanner | StepOverPlanner:
        robot = self.robot()
        if self.options.mode == "grasp":
            from marionette.footsteps.planner import GraspPlanner, GraspPlannerOptions

            grasp = GraspPlanner(
                robot, stance, pose[:3], options=GraspPlannerOptions(hand=self.options.hand)
            )
            grasp.plan()
            return grasp
        from marionette.footsteps.step_over import StepOverOptions, StepOverPlanner

        bar = Bar(pose[:2], pose[3], self.options.bar_radius, self.options.bar_length)
        step_over = StepOverPlanner(
            stance,
            np.array(self.options.goal),
            bar,
            robot.foot,
            options=StepOverOptions(swing_margin=self.options.swing_margin).with_crossing_duration(
                self.options.crossing_duration
            ),
        )
        step_over.plan()
        return step_over

    def _replan(
        self, planner: GraspPlanner | StepOverPlanner, pose: np.ndarray, executed: int
    ) -> None:
        from marionette.footsteps.planner import GraspPlanner

        if isinstance(planner, GraspPlanner):
            planner.replan(
                pose[:3], executed_steps=executed, posture_frozen=self.options.posture_frozen
            )
        else:
            bar = planner.bar.moved_to(pose[:2], pose[3])
            planner.update_bar(bar, executed_steps=executed)


def run(
    options: NodeOptions,
    lcm_url: str | None = None,
    rate_hz: float = 50.0,
    stance: Stance | None = None,
    duration_s: float | None = None,
) -> int:
    """The process: subscribe, replan at ``rate_hz`` when needed, publish FOOTSTEP_PLAN."""
    from marionette import channels, lcmt_object_poses, lcmt_walk_status
    from marionette.lcm_bus import LcmBus

    node = FootstepNode(options, stance)
    with LcmBus(lcm_url) as bus:
        bus.subscribe(channels.OBJECT_POSES, lcmt_object_poses, node.on_object_poses)
        bus.subscribe(channels.WALK_STATUS, lcmt_walk_status, node.on_walk_status)
        bus.start()
        print(f"footsteps: ready ({options.mode}) on {bus.url}", flush=True)
        start = time.monotonic()
        period = 1.0 / rate_hz
        try:
            _loop(node, bus, start, period, duration_s)
        except KeyboardInterrupt:  # SIGINT is how ProcessGroup and a terminal stop the process
            print("footsteps: stopped", flush=True)
    return 0


def _loop(node: FootstepNode, bus, start: float, period: float, duration_s: float | None) -> None:
    from marionette import channels

    while duration_s is None or time.monotonic() - start < duration_s:
        tick = time.monotonic()
        try:
            msg = node.update(int(1e6 * time.time()))
        except FootstepError as exc:
            print(f"footsteps: planning failed: {exc}", flush=True)
            msg = None
        if msg is not None:
            bus.publish(channels.FOOTSTEP_PLAN, msg)
            print(
                f"footsteps: plan {msg.plan_id} from step {msg.first_step_index}, "
                f"{msg.num_steps} steps ({node.last_solve_ms:.1f} ms)",
                flush=True,
            )
        time.sleep(max(0.0, period - (time.monotonic() - tick)))
