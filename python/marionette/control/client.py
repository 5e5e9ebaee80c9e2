"""A Python handle on a running marionette-controller: send specs, references, commands and
simulator perturbations; read its state and status; wait for conditions."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from marionette import (
    channels,
    lcmt_camera_image,
    lcmt_command,
    lcmt_controller_status,
    lcmt_object_poses,
    lcmt_robot_command,
    lcmt_robot_state,
    lcmt_sim_command,
)
from marionette.control.spec import ControllerSpec
from marionette.lcm_bus import LcmBus
from marionette.processes import ManagedProcess


def pose_to_vector(X) -> np.ndarray:
    """pinocchio.SE3 -> (x y z qw qx qy qz), the layout of SE3 references on the wire."""
    import pinocchio as pin

    q = pin.Quaternion(X.rotation)
    return np.array([*X.translation, q.w, q.x, q.y, q.z])


def vector_to_pose(v):
    """(x y z qw qx qy qz) -> pinocchio.SE3."""
    import pinocchio as pin

    v = np.asarray(v, dtype=float)
    quat = pin.Quaternion(v[3], v[4], v[5], v[6])
    quat.normalize()
    return pin.SE3(quat.matrix(), v[:3].copy())


class ControllerClient:
    """Keeps the latest ROBOT_STATE, ROBOT_COMMAND, CONTROLLER_STATUS, SIM_OBJECT_POSES and
    camera frame of one controller (handled in a background thread) and sends it messages."""

    def __init__(self, lcm_url: str | None = None, camera: bool = False) -> None:
        self.bus = LcmBus(lcm_url)
        self._lock = threading.Condition()
        self.state: Any = None
        self.command: Any = None
        self.status: Any = None
        self.objects: Any = None
        self.image: Any = None
        self.num_states = 0
        self.num_images = 0
        self.image_utimes: list[int] = []  # controller time of every frame received
        # The controller's process, set by whoever started it (benchmarks, tests): None otherwise.
        self.process: ManagedProcess | None = None
        self.bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on("state"))
        self.bus.subscribe(channels.ROBOT_COMMAND, lcmt_robot_command, self._on("command"))
        self.bus.subscribe(channels.CONTROLLER_STATUS, lcmt_controller_status, self._on("status"))
        self.bus.subscribe(channels.SIM_OBJECT_POSES, lcmt_object_poses, self._on("objects"))
        if camera:
            self.bus.subscribe(channels.CAMERA_HEAD, lcmt_camera_image, self._on("image"))
        self.bus.start()

    def _on(self, attribute: str) -> Callable[[Any], None]:
        def handler(msg: Any) -> None:
            with self._lock:
                setattr(self, attribute, msg)
                if attribute == "state":
                    self.num_states += 1
                if attribute == "image":
                    self.num_images += 1
                    self.image_utimes.append(msg.utime)
                self._lock.notify_all()

        return handler

    def close(self) -> None:
        self.bus.stop()

    def __enter__(self) -> ControllerClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- waiting ---------------------------------------------------------------------------
    def wait(
        self, condition: Callable[[ControllerClient], bool], timeout_s: float, what: str = ""
    ) -> None:
        """Blocks until ``condition(self)`` holds; raises TimeoutError naming ``what``."""
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while True:
                try:
                    if condition(self):
                        return
                except (AttributeError, IndexError, TypeError):
                    pass  # nothing received yet
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(self.timeout_message(timeout_s, what or str(condition)))
                self._lock.wait(min(remaining, 0.05))

    def timeout_message(self, timeout_s: float, what: str) -> str:
        """ "timed out after <timeout_s> s waiting for <what>" and what the controller last said."""
        status = self.status
        detail = (
            f" (mode {status.mode!r}: {status.mode_reason}; last rejection: "
            f"{status.last_rejection!r}; last switch: {status.last_switch_result!r})"
            if status is not None
            else " (no CONTROLLER_STATUS received)"
        )
        return f"timed out after {timeout_s:g} s waiting for {what}{detail}"

    def wait_ready(self, timeout_s: float = 30.0, processes: Any = None) -> None:
        """Waits for the controller's first state and status. ``processes`` (a
        :class:`~marionette.processes.ProcessGroup` that started it): a process of it that exits
        meanwhile ends the wait at once (ProcessError with its log's tail, it usually says why),
        not at the timeout: a controller refusing its arguments exits in milliseconds."""

        def ready(c: ControllerClient) -> bool:
            if c.status is not None and c.state is not None:
                return True
            if processes is not None:
                processes.check_alive()
            return False

        try:
            self.wait(ready, timeout_s, "the controller")
        except TimeoutError:
            if processes is not None:
                processes.check_alive()
            raise

    def wait_past(self, utime: int, timeout_s: float, what: str) -> None:
        """Waits until the controller's clock is past ``utime`` [us]."""
        self.wait(lambda c: c.utime() > utime, timeout_s, what)

    def wait_time(self, seconds: float, timeout_s: float | None = None) -> None:
        """Waits until the controller's clock has advanced by ``seconds``."""
        start = self.state.utime
        self.wait(
            lambda c: c.state.utime >= start + seconds * 1e6,
            timeout_s if timeout_s is not None else 10.0 + 5.0 * seconds,
            f"{seconds} s of controller time",
        )

    # ---- sending ---------------------------------------------------------------------------
    def send_spec(self, spec: ControllerSpec) -> None:
        self.bus.publish(channels.CONTROLLER_SPEC, spec.to_lcm(self.utime()))

    def send_command(self, command: str, source: str = "python", reason: str = "") -> None:
        msg = lcmt_command()
        msg.utime = self.utime()
        msg.command, msg.source, msg.reason = command, source, reason
        self.bus.publish(channels.COMMAND, msg)

    def send_reference(self, chunk) -> None:
        self.bus.publish(channels.TASK_REFERENCE, chunk)

    def move_object(self, name: str, X) -> None:
        """Teleports a free object of the MuJoCo scene (a perturbation)."""
        self._pose_command("set_object_pose", name, X)

    def slide_object(self, name: str, X, duration_s: float) -> None:
        """Carries a mocap body of the MuJoCo scene (a fixture: a bar, a cart) to the pose ``X``
        at constant speed over ``duration_s`` of simulated time (a physical move: the cameras
        see it move and the robot's contacts meet it where it is)."""
        self._pose_command("slide", name, X, duration_s)

    def push_object(self, name: str, force_W, duration_s: float) -> None:
        """Pushes a free object of the MuJoCo scene with ``force_W`` [N] (world axes, at its
        centre of mass) for ``duration_s`` of simulated time (a physical perturbation)."""
        msg = lcmt_sim_command()
        msg.utime = self.utime()
        msg.command = "push"
        msg.object_name = name
        msg.quaternion = [1.0, 0.0, 0.0, 0.0]
        msg.force = [float(f) for f in force_W]
        msg.duration = float(duration_s)
        self.bus.publish(channels.SIM_COMMAND, msg)

    def set_friction(self, name: str, mu: float) -> None:
        """Gives a free object of the MuJoCo scene the sliding friction coefficient ``mu`` in
        every contact it makes (a physical perturbation: an object gone slippery)."""
        msg = lcmt_sim_command()
        msg.utime = self.utime()
        msg.command = "set_friction"
        msg.object_name = name
        msg.quaternion = [1.0, 0.0, 0.0, 0.0]
        msg.friction = float(mu)
        self.bus.publish(channels.SIM_COMMAND, msg)

    def attach(self, weld: str) -> None:
        """Simulated grasp: activates the scene's weld ("grasp/<robot>/<gripper>/<object>")
        at the current relative pose of its bodies."""
        self._sim_command("attach", weld)

    def detach(self, weld: str) -> None:
        self._sim_command("detach", weld)

    def _pose_command(self, command: str, name: str, X, duration_s: float = 0.0) -> None:
        """SIM_COMMAND ``command`` moving ``name`` to the pose ``X`` (over ``duration_s``)."""
        msg = lcmt_sim_command()
        msg.utime = self.utime()
        msg.command, msg.object_name = command, name
        v = pose_to_vector(X)
        msg.position, msg.quaternion = list(v[:3]), list(v[3:])
        msg.duration = float(duration_s)
        self.bus.publish(channels.SIM_COMMAND, msg)

    def _sim_command(self, command: str, name: str) -> None:
        msg = lcmt_sim_command()
        msg.utime = self.utime()
        msg.command, msg.object_name = command, name
        msg.quaternion = [1.0, 0.0, 0.0, 0.0]
        self.bus.publish(channels.SIM_COMMAND, msg)

    # ---- reading ---------------------------------------------------------------------------
    def utime(self) -> int:
        """The controller's latest time [us] (0 before any state)."""
        return int(self.state.utime) if self.state is not None else 0

    def joint_positions(self) -> dict[str, float]:
        s = self.state
        return dict(zip(s.joint_name, s.joint_position))

    def base_position(self) -> np.ndarray:
        return np.array(self.state.base_position)

    def object_pose(self, name: str):
        """Ground-truth pose of a free object (simulator), pinocchio.SE3."""
        for o in self.objects.objects:
            if o.object_name == name:
                return vector_to_pose([*o.position_world, *o.quaternion_world])
        raise KeyError(f"no object {name!r} in SIM_OBJECT_POSES")

    def task_error(self, name: str) -> float:
        s = self.status
        return dict(zip(s.task_name, s.task_error_norm))[name]


def configuration_from_state(model, state) -> np.ndarray:
    """The robot's Pinocchio configuration (nq) from an ``lcmt_robot_state``: base pose from
    its base fields (free-flyer or planar root joint), joints by name."""
    import pinocchio as pin

    q = pin.neutral(model)
    positions = dict(zip(state.joint_name, state.joint_position))
    for j in range(1, model.njoints):
        joint = model.joints[j]
        name = model.names[j]
        if joint.shortname() == "JointModelFreeFlyer":
            w, x, y, z = state.base_quaternion
            q[joint.idx_q : joint.idx_q + 7] = [*state.base_position, x, y, z, w]
        elif joint.shortname() == "JointModelPlanar":
            w, _, _, z = state.base_quaternion
            yaw = 2.0 * np.arctan2(z, w)
            q[joint.idx_q : joint.idx_q + 4] = [
                state.base_position[0],
                state.base_position[1],
                np.cos(yaw),
                np.sin(yaw),
            ]
        elif name in positions:
            q[joint.idx_q] = positions[name]
    return q
