"""The augmented robot (Kanoun's "centipede", Dang §2.5.2): the robot + k virtual planar joints.

Footprints. The two feet on the floor before walking are P_-1 (the foot that moves first) and
P_0 (the stance foot, root of the chain). Step i (1..k) moves the foot that stood at P_(i-2) to

    P_i = P_(i-1) ∘ (Δx_i, Δy_i, Δθ_i)                                   (Dang eq. 2.82–2.83)

i.e. Δ_i is the planar pose of footprint i in the frame of footprint i-1 (the other foot), so
the step limits of eq. 2.82 are plain joint limits of the virtual joint i. Footprints alternate
feet: P_i is on the side of P_(i-2).

Robot. The real robot stands at the end of the chain, with the sole of the side of P_k on P_k
and the other sole on P_(k-1). Its configuration ``q_robot`` (nq) has its free-flyer expressed in
the frame L of the last footprint (origin at the sole centre on the floor, z up), so the robot's
forward kinematics do not depend on the steps and world poses compose as X_W,f = X_W,Pk · X_L,f.
The augmented configuration is [Δ_1 .. Δ_k, q_robot] (eq. 2.83, ordered as eq. 6.1); its tangent
vector is [Δ (3k), v_robot (nv)].

Jacobians are analytic (exact): for a point c rigidly attached to footprint i,
    ∂c/∂(Δx_j, Δy_j) = R(θ_(j-1)),   ∂c/∂Δθ_j = S (c − p_j)   for j ≤ i, 0 otherwise,
with S the +90° rotation (Δθ_j turns everything downstream about p_j).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
import pinocchio as pin

from marionette.footsteps.errors import InvalidProblem
from marionette.footsteps.robot_model import FootShape, RobotDescription

SIDES = ("left", "right")


class RobotKinematics(TypedDict):
    """The robot's kinematics in the frame L of the last footprint (one configuration)."""

    frames: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]  # name -> p (3,), R, J (6, nv)
    com: np.ndarray  # (3,)
    J_com: np.ndarray  # (3, nv)


def rotation_2d(theta: np.ndarray) -> np.ndarray:
    """Planar rotation matrices: theta (...,) -> (..., 2, 2)."""
    theta = np.asarray(theta, dtype=float)
    c, s = np.cos(theta), np.sin(theta)
    out = np.empty(theta.shape + (2, 2))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    return out


def rotation_z(theta: float) -> np.ndarray:
    """3x3 rotation about world z."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def planar_relative(parent: np.ndarray, child: np.ndarray) -> np.ndarray:
    """Pose (x, y, yaw) of ``child`` in the frame of ``parent`` (both world (x, y, yaw))."""
    d = rotation_2d(parent[2]).T @ (child[:2] - parent[:2])
    return np.array([d[0], d[1], wrap_angle(child[2] - parent[2])])


def planar_compose(parent: np.ndarray, relative: np.ndarray) -> np.ndarray:
    """World pose of a frame at ``relative`` (x, y, yaw) in ``parent`` (x, y, yaw)."""
    p = parent[:2] + rotation_2d(parent[2]) @ relative[:2]
    return np.array([p[0], p[1], parent[2] + relative[2]])


def wrap_angle(a):
    """Angle(s) wrapped to (-pi, pi]."""
    return -((-np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi)


@dataclass(frozen=True)
class Stance:
    """The two soles on the floor before the first step: world (x, y, yaw) [m, m, rad]."""

    left: np.ndarray
    right: np.ndarray
    floor_z: float = 0.0

    def __post_init__(self) -> None:
        for name in ("left", "right"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise InvalidProblem(
                    f"stance.{name} must be 3 finite numbers (x, y, yaw), "
                    f"got {getattr(self, name)!r}"
                )
            object.__setattr__(self, name, value)

    def foot(self, side: str) -> np.ndarray:
        return self.left if side == "left" else self.right


@dataclass
class AugmentedConfiguration:
    """A point of the augmented robot's configuration space.

    ``steps`` (k, 3): Δx, Δy [m], Δθ [rad] of footprint i in the frame of footprint i-1.
    ``q_robot`` (nq,) or None for a footsteps-only chain (Dang §3.3).
    """

    steps: np.ndarray
    q_robot: np.ndarray | None = None

    @property
    def num_steps(self) -> int:
        return int(self.steps.shape[0])

    def copy(self) -> AugmentedConfiguration:
        return AugmentedConfiguration(
            self.steps.copy(), None if self.q_robot is None else self.q_robot.copy()
        )

    def require_q_robot(self) -> np.ndarray:
        """``q_robot``; raises InvalidProblem for a footsteps-only configuration."""
        if self.q_robot is None:
            raise InvalidProblem("this configuration has no robot posture (footsteps only)")
        return self.q_robot


class AugmentedRobot:
    """Robot + virtual planar chain (see module doc). Immutable; evaluate() gives kinematics.

    ``robot`` may be None: footsteps alone, the "upper body transparent" problem of Dang §3.3.
    ``first_side``: the foot that makes step 1 (its current sole is P_-1).
    """

    def __init__(
        self,
        robot: RobotDescription | None,
        stance: Stance,
        first_side: str,
        foot: FootShape | None = None,
    ) -> None:
        if first_side not in SIDES:
            raise InvalidProblem(f"first_side must be 'left' or 'right', got {first_side!r}")
        if foot is None:
            if robot is None:
                raise InvalidProblem("a footsteps-only chain needs a FootShape")
            foot = robot.foot
        self.robot = robot
        self.stance = stance
        self.first_side = first_side
        self.stance_side = "left" if first_side == "right" else "right"
        self.foot = foot
        self.foot_corners = self.foot.corners()  # (4, 2) sole frame
        self.foot_corners.flags.writeable = False
        self.root = stance.foot(self.stance_side)  # P_0
        self.initial_moving = stance.foot(first_side)  # P_-1
        self._robot_cache: tuple[bytes, RobotKinematics] | None = None  # (q_robot bytes, ...)
        self._is_left_cache: dict[int, np.ndarray] = {}

    # -- sides and sizes ---------------------------------------------------------------------
    def side_of(self, i: int) -> str:
        """Side ("left"/"right") of footprint i (i ≥ -1): step i moves the foot of P_(i-2)."""
        return self.first_side if (i % 2 != 0) else self.stance_side

    def is_left(self, k: int) -> np.ndarray:
        """(k + 2,) bool, footprints -1..k (read-only, cached)."""
        cached = self._is_left_cache.get(k)
        if cached is None:
            odd = (np.arange(-1, k + 1) % 2) != 0
            first_left = self.first_side == "left"
            cached = np.where(odd, first_left, not first_left)
            cached.flags.writeable = False
            self._is_left_cache[k] = cached
        return cached

    def nv_robot(self) -> int:
        return 0 if self.robot is None else self.robot.model.nv

    def require_robot(self) -> RobotDescription:
        """The robot; raises InvalidProblem for a footsteps-only chain."""
        if self.robot is None:
            raise InvalidProblem("this augmented robot has no robot (footsteps only)")
        return self.robot

    # -- configurations ----------------------------------------------------------------------
    def neutral_configuration(self, k: int = 0) -> AugmentedConfiguration:
        """k in-place steps (each foot lands where it stood) and the reference posture."""
        config = AugmentedConfiguration(np.zeros((0, 3)), None)
        if self.robot is not None:
            config.q_robot = self.standing_configuration(self.side_of(0))
        for _ in range(k):
            config = self.add_step(config)
        return config

    def standing_configuration(self, last_side: str) -> np.ndarray:
        """Reference posture with the ``last_side`` sole on the origin of frame L (q_robot)."""
        robot = self.require_robot()
        q = robot.reference_posture.copy()
        model, data = robot.model, robot.data
        pin.framesForwardKinematics(model, data, q)
        X_LB = pin.SE3(np.eye(3), np.zeros(3))
        X_base = data.oMi[1]
        X_sole = data.oMf[model.getFrameId(robot.sole_frames[last_side])]
        # Keep the sole flat: take only its yaw and position, so that L = the sole's floor frame.
        yaw = np.arctan2(X_sole.rotation[1, 0], X_sole.rotation[0, 0])
        X_Wsole_flat = pin.SE3(rotation_z(yaw), X_sole.translation)
        X_LB = X_Wsole_flat.inverse() * X_base
        q[:7] = pin.SE3ToXYZQUAT(X_LB)
        return q

    def integrate(self, config: AugmentedConfiguration, dv: np.ndarray) -> AugmentedConfiguration:
        """config ⊕ dv, dv = [Δsteps (3k), v_robot (nv)] (nv part optional when robot frozen)."""
        k3 = 3 * config.num_steps
        steps = config.steps + dv[:k3].reshape(-1, 3)
        q_robot = config.q_robot
        if q_robot is not None and dv.shape[0] > k3:
            q_robot = pin.integrate(self.require_robot().model, q_robot, dv[k3:])
        return AugmentedConfiguration(steps, q_robot)

    def footprints(self, steps: np.ndarray) -> np.ndarray:
        """World (x, y, yaw) of footprints -1..k: (k + 2, 3)."""
        k = steps.shape[0]
        out = np.empty((k + 2, 3))
        out[0] = self.initial_moving
        out[1] = self.root
        if k:
            theta = np.empty(k + 1)  # θ_0..θ_k
            theta[0] = self.root[2]
            np.cumsum(steps[:, 2], out=theta[1:])
            theta[1:] += self.root[2]
            c, s = np.cos(theta[:-1]), np.sin(theta[:-1])  # R(θ_(i-1))
            out[2:, 0] = c * steps[:, 0] - s * steps[:, 1]
            out[2:, 1] = s * steps[:, 0] + c * steps[:, 1]
            np.cumsum(out[2:, :2], axis=0, out=out[2:, :2])
            out[2:, :2] += self.root[:2]
            out[2:, 2] = theta[1:]
        return out

    def add_step(
        self, config: AugmentedConfiguration, nominal_width: float = 0.17
    ) -> AugmentedConfiguration:
        """Algorithm 1's new virtual link, appended at the end of the chain.

        With a robot, step k+1 lands in place (where P_(k-1) is), the robot moving onto it
        without moving in the world: every task value is unchanged, and the posture still fits
        its two footprints. Without a robot, the new foot lands beside the last one
        (Δ = (0, ±nominal_width, 0)): an in-place step there would start as a backward step.
        """
        k = config.num_steps
        fp = self.footprints(config.steps)
        last, previous = fp[k + 1], fp[k]
        if self.robot is None:
            sign = 1.0 if self.side_of(k + 1) == "left" else -1.0
            new_step = np.array([0.0, sign * nominal_width, 0.0])
        else:
            new_step = planar_relative(last, previous)
        steps = np.vstack([config.steps, new_step])
        q_robot = self._reattach(config.q_robot, last, previous)
        return AugmentedConfiguration(steps, q_robot)

    def remove_last_step(self, config: AugmentedConfiguration) -> AugmentedConfiguration:
        """Inverse of :meth:`add_step`: drop step k; the robot moves onto P_(k-1) (world fixed)."""
        k = config.num_steps
        if k == 0:
            raise InvalidProblem("no step to remove")
        fp = self.footprints(config.steps)
        q_robot = self._reattach(config.q_robot, fp[k + 1], fp[k])
        return AugmentedConfiguration(config.steps[:-1].copy(), q_robot)

    def _reattach(
        self, q_robot: np.ndarray | None, old: np.ndarray, new: np.ndarray
    ) -> np.ndarray | None:
        """q_robot re-expressed from footprint frame ``old`` to ``new`` (world unchanged)."""
        if q_robot is None:
            return None
        q = q_robot.copy()
        X_W_old = self.footprint_se3(old)
        X_W_new = self.footprint_se3(new)
        X_old_B = pin.XYZQUATToSE3(q[:7])
        q[:7] = pin.SE3ToXYZQUAT(X_W_new.inverse() * X_W_old * X_old_B)
        return q

    def footprint_se3(self, pose: np.ndarray) -> pin.SE3:
        """SE3 of a footprint (x, y, yaw) on the floor."""
        return pin.SE3(rotation_z(pose[2]), np.array([pose[0], pose[1], self.stance.floor_z]))

    # -- kinematics --------------------------------------------------------------------------
    def evaluate(
        self, config: AugmentedConfiguration, robot_free: bool = True
    ) -> AugmentedKinematics:
        """Footprints, robot frames and their Jacobians at ``config``.

        ``robot_free`` False: the posture is frozen; Jacobians then have only the 3k step columns.
        """
        if (self.robot is None) != (config.q_robot is None):
            raise InvalidProblem(
                "q_robot must be given exactly when the augmented robot has a robot"
            )
        robot_data = None
        if config.q_robot is not None:
            robot_data = self._robot_kinematics(config.q_robot)
        return AugmentedKinematics(self, config, robot_data, robot_free and self.robot is not None)

    def _robot_kinematics(self, q_robot: np.ndarray) -> RobotKinematics:
        """Frame placements / Jacobians in frame L; cached while q_robot does not change."""
        key = q_robot.tobytes()
        if self._robot_cache is not None and key == self._robot_cache[0]:
            return self._robot_cache[1]
        robot = self.require_robot()
        if q_robot.shape != (robot.model.nq,) or not np.all(np.isfinite(q_robot)):
            raise InvalidProblem(f"q_robot must be {robot.model.nq} finite numbers")
        model, data = robot.model, robot.data
        pin.computeJointJacobians(model, data, q_robot)
        pin.updateFramePlacements(model, data)
        frames = {}
        names = {*robot.sole_frames.values(), *robot.hand_frames.values(), robot.camera_frame}
        for name in names:
            fid = model.getFrameId(name)
            X = data.oMf[fid]
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            frames[name] = (X.translation.copy(), X.rotation.copy(), J.copy())
        J_com = pin.jacobianCenterOfMass(model, data, q_robot, False)
        out = RobotKinematics(frames=frames, com=data.com[0].copy(), J_com=J_com.copy())
        self._robot_cache = (key, out)
        return out


class AugmentedKinematics:
    """Kinematics of the augmented robot at one configuration (read-only arrays).

    Column layout of every Jacobian: [steps (3k) | robot (nv) if the robot is free].
    Footprint indices run -1..k (P_-1 and P_0 are fixed: zero Jacobian).
    """

    def __init__(
        self,
        augmented: AugmentedRobot,
        config: AugmentedConfiguration,
        robot_data: RobotKinematics | None,
        robot_free: bool,
    ) -> None:
        self.augmented = augmented
        self.config = config
        self.k = config.num_steps
        self.footprints = augmented.footprints(config.steps)  # (k + 2, 3)
        self.is_left = augmented.is_left(self.k)  # (k + 2,)
        self.robot_free = robot_free
        self.nv_steps = 3 * self.k
        self.nv_robot = augmented.nv_robot() if robot_free else 0
        self.nv = self.nv_steps + self.nv_robot
        self._robot = robot_data
        self._rot_last = rotation_z(self.footprints[-1, 2])

    # The Jacobians' shared blocks are built on first use: the line search evaluates candidate
    # configurations for their values alone.
    @functools.cached_property
    def _rot_prev(self) -> np.ndarray:
        """(k, 2, 2): R(θ_(j-1)) of every step j."""
        return rotation_2d(self.footprints[1:-1, 2])

    @functools.cached_property
    def _xy_columns(self) -> np.ndarray:
        """Translation columns of a point attached to the last footprint: R(θ_(j-1)) per step."""
        columns = np.zeros((2, self.nv))
        if self.k:
            view = columns[:, : 3 * self.k].reshape(2, self.k, 3)
            view[:, :, :2] = np.transpose(self._rot_prev, (1, 0, 2))
        return columns

    # -- footprints --------------------------------------------------------------------------
    def footprint(self, i: int) -> np.ndarray:
        """World (x, y, yaw) of footprint i (-1..k)."""
        return self.footprints[i + 1]

    def points_jacobian(self, points: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        """Jacobian of world points (m, 2) rigidly attached to footprints (m,): (m, 2, nv)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        footprint = np.asarray(footprint, dtype=int).reshape(-1)
        m, k = points.shape[0], self.k
        out = np.zeros((m, 2, self.nv))
        if k == 0:
            return out
        mask = (np.arange(1, k + 1)[None, :] <= footprint[:, None]).astype(float)  # (m, k)
        blocks = np.empty((m, 2, k, 3))
        blocks[:, :, :, :2] = np.transpose(self._rot_prev, (1, 0, 2))[None]  # R(θ_(j-1))
        d = points[:, None, :] - self.footprints[None, 2:, :2]  # c − p_j
        blocks[:, 0, :, 2] = -d[..., 1]
        blocks[:, 1, :, 2] = d[..., 0]
        blocks *= mask[:, None, :, None]
        out[:, :, : 3 * k] = blocks.reshape(m, 2, 3 * k)
        return out

    def yaw_jacobian(self, footprint: np.ndarray) -> np.ndarray:
        """Jacobian of the yaw of footprints (m,): (m, nv) (1 on every Δθ_j, j ≤ i)."""
        footprint = np.asarray(footprint, dtype=int).reshape(-1)
        out = np.zeros((footprint.shape[0], self.nv))
        if self.k:
            mask = np.arange(1, self.k + 1)[None, :] <= footprint[:, None]
            out[:, 2 : 3 * self.k : 3] = mask
        return out

    def footprint_jacobian(self, i: int) -> np.ndarray:
        """Jacobian of footprint i's (x, y, yaw): (3, nv)."""
        out = np.zeros((3, self.nv))
        if i >= 1:
            n = 3 * i
            out[:2, :n] = self._xy_columns[:, :n]
            d = self.footprints[i + 1, :2] - self.footprints[2 : i + 2, :2]
            out[0, 2:n:3] = -d[:, 1]
            out[1, 2:n:3] = d[:, 0]
            out[2, 2:n:3] = 1.0
        return out

    def corners(self, indices: np.ndarray) -> np.ndarray:
        """World corners of the foot rectangles of footprints ``indices`` (m,): (m, 4, 2)."""
        fp = self.footprints[np.asarray(indices) + 1]
        rot = rotation_2d(fp[:, 2])
        return fp[:, None, :2] + np.einsum("mab,cb->mca", rot, self.augmented.foot_corners)

    # -- robot frames ------------------------------------------------------------------------
    def _require_robot(self) -> RobotKinematics:
        if self._robot is None:
            raise InvalidProblem("this augmented robot has no robot (footsteps only)")
        return self._robot

    def frame_placement(self, frame: str) -> tuple[np.ndarray, np.ndarray]:
        """World position (3,) and rotation (3, 3) of a robot frame."""
        p_L, R_L, _ = self._require_robot()["frames"][frame]
        last = self.footprints[-1]
        p = np.array([last[0], last[1], self.augmented.stance.floor_z]) + self._rot_last @ p_L
        return p, self._rot_last @ R_L

    def frame_jacobian(self, frame: str) -> np.ndarray:
        """World-aligned Jacobian [linear; angular] of a robot frame: (6, nv)."""
        _p_L, _, J_L = self._require_robot()["frames"][frame]
        p_W, _ = self.frame_placement(frame)
        return self._attached_jacobian(p_W, J_L)

    def com(self) -> np.ndarray:
        """World centre of mass (3,)."""
        robot = self._require_robot()
        last = self.footprints[-1]
        return (
            np.array([last[0], last[1], self.augmented.stance.floor_z])
            + self._rot_last @ robot["com"]
        )

    def com_jacobian(self) -> np.ndarray:
        """Jacobian of the world centre of mass: (3, nv)."""
        robot = self._require_robot()
        J6 = np.zeros((6, robot["J_com"].shape[1]))
        J6[:3] = robot["J_com"]
        return self._attached_jacobian(self.com(), J6)[:3]

    def _attached_jacobian(self, p_W: np.ndarray, J_L: np.ndarray) -> np.ndarray:
        out = np.zeros((6, self.nv))
        out[:2] = self._xy_columns
        if self.k:
            # Δθ_j turns the robot about world z through p_j: ∂p/∂Δθ_j = S (p − p_j).
            d = p_W[:2] - self.footprints[2:, :2]
            out[0, 2 : 3 * self.k : 3] = -d[:, 1]
            out[1, 2 : 3 * self.k : 3] = d[:, 0]
            out[5, 2 : 3 * self.k : 3] = 1.0
        if self.robot_free:
            R = self._rot_last
            out[:3, self.nv_steps :] = R @ J_L[:3]
            out[3:, self.nv_steps :] = R @ J_L[3:]
        return out
