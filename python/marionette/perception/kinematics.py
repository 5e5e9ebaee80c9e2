"""Robot kinematics for perception: where the camera is, from the measured robot state.

``lcmt_robot_state`` carries joint positions by name and the base pose; the camera's world pose
X_WC is the Pinocchio forward kinematics of the optical frame (x right, y down, z forward) at
that configuration (thesis 000 §3.3.6: Agimus-Vision publishes poses relative to the robot).
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np
import pinocchio as pin


class StateError(ValueError):
    """A robot state message does not fit the model; the message says why."""


def configuration_from_state(model: pin.Model, msg) -> np.ndarray:
    """Pinocchio q (nq,) from an ``lcmt_robot_state``.

    Base: free flyer from ``base_position`` and ``base_quaternion`` (w, x, y, z); planar from
    the position's x, y and the yaw of the quaternion; fixed bases ignore them. Every 1-dof
    joint of the model must be named in the message; extra names are ignored.
    """
    q = pin.neutral(model)
    root = model.joints[1] if model.njoints > 1 else None
    if root is not None and model.names[1] == "root_joint":
        p = np.asarray(msg.base_position, dtype=float)
        w, x, y, z = (float(a) for a in msg.base_quaternion)
        norm = np.sqrt(w * w + x * x + y * y + z * z)
        if not (np.all(np.isfinite(p)) and np.isfinite(norm) and norm > 0.5):
            raise StateError(
                f"base pose is not finite or its quaternion is not unit (|q| = {norm})"
            )
        w, x, y, z = w / norm, x / norm, y / norm, z / norm
        if root.nq == 7:
            q[:7] = [*p, x, y, z, w]
        elif root.nq == 4:
            yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            q[:4] = [p[0], p[1], np.cos(yaw), np.sin(yaw)]
    positions = dict(zip(msg.joint_name, msg.joint_position))
    missing = []
    for j in range(1, model.njoints):
        joint = model.joints[j]
        name = model.names[j]
        if joint.nq != 1:
            continue
        if name not in positions:
            missing.append(name)
            continue
        value = float(positions[name])
        if not np.isfinite(value):
            raise StateError(f"joint {name} position is not finite")
        q[joint.idx_q] = value
    if missing:
        raise StateError(
            f"robot state lacks joints {missing[:5]}{'...' if len(missing) > 5 else ''}"
        )
    return q


class StateHistory:
    """The latest measured robot configurations (thread-safe): the last ``history`` states,
    answered for the one whose ``utime`` is closest to a given instant, so that a 30 Hz camera
    meets the 100 Hz state stream at the right instant; with the pose of any frame there."""

    def __init__(self, model: pin.Model, history: int = 200) -> None:
        self.model = model
        self.data = model.createData()
        self._states: deque = deque(maxlen=history)
        self._lock = threading.Lock()

    def add_state(self, msg) -> None:
        """Stores a state (raises StateError if it does not fit the model)."""
        q = configuration_from_state(self.model, msg)
        with self._lock:
            self._states.append((int(msg.utime), q))

    def has_state(self) -> bool:
        with self._lock:
            return bool(self._states)

    def nearest(self, utime: int) -> tuple[np.ndarray, int] | None:
        """(q, its utime) for the state nearest ``utime``, or None before any state."""
        with self._lock:
            if not self._states:
                return None
            t, q = min(self._states, key=lambda s: abs(s[0] - utime))
        return q, t

    def frame_pose_at(self, frame_id: int, q: np.ndarray) -> pin.SE3:
        pin.framesForwardKinematics(self.model, self.data, q)
        return pin.SE3(self.data.oMf[frame_id])

    def frame_pose(self, frame_id: int, utime: int) -> tuple[pin.SE3, int] | None:
        """(X_WF, state utime) for the state nearest ``utime``, or None before any state."""
        found = self.nearest(utime)
        if found is None:
            return None
        q, t = found
        return self.frame_pose_at(frame_id, q), t


class CameraKinematics(StateHistory):
    """X_WC of the robot's camera frame from the latest robot states (:class:`StateHistory`)."""

    def __init__(self, model: pin.Model, camera_frame: str, history: int = 200) -> None:
        if not model.existFrame(camera_frame):
            raise ValueError(f"model {model.name} has no frame {camera_frame!r}")
        super().__init__(model, history)
        self.frame_id = model.getFrameId(camera_frame)

    def camera_pose(self, utime: int) -> tuple[pin.SE3, int] | None:
        """(X_WC, state utime) for the state nearest ``utime``, or None before any state."""
        return self.frame_pose(self.frame_id, utime)

    def camera_pose_at(self, q: np.ndarray) -> pin.SE3:
        return self.frame_pose_at(self.frame_id, q)
