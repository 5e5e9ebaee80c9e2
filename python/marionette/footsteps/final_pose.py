"""Posture-frozen replanning, first half: where the frozen robot must stand (Dang §6.2.2).

With the posture frozen the robot is one rigid body standing on its last footprint P_k, so
every robot task (hand, gaze, facing) is a function of P_k = (x, y, θ) alone. The prioritised
problem then splits exactly in two while the step constraints leave P_k free to move:

1. this module: the hierarchy of robot tasks over the 3 dofs of P_k → the stance P_k*;
2. the chain (footsteps only, Dang §3.3): reach P_k* with the executed steps frozen, under the
   step limits, non-overlap and obstacle constraints (Algorithm 1 adds steps if it cannot).

:class:`RigidStanceKinematics` duck-types the part of
:class:`~marionette.footsteps.augmented_robot.AugmentedKinematics` the robot tasks read, with
Jacobian columns (x, y, θ) of P_k.
"""

from __future__ import annotations

import numpy as np

from marionette.footsteps.augmented_robot import rotation_z


class RigidStanceKinematics:
    """Robot frames of a frozen posture standing on footprint ``pose`` (x, y, θ)."""

    k = 1
    robot_free = False
    nv = 3

    def __init__(self, pose: np.ndarray, frames_L: dict, floor_z: float) -> None:
        self.pose = np.asarray(pose, dtype=float)
        self._frames = frames_L  # name -> (p_L (3,), R_L (3, 3))
        self._floor_z = floor_z
        self._R = rotation_z(self.pose[2])
        self._placements: dict = {}

    def footprint(self, i: int) -> np.ndarray:
        return self.pose

    def footprint_jacobian(self, i: int) -> np.ndarray:
        return np.eye(3)

    def frame_placement(self, frame: str) -> tuple[np.ndarray, np.ndarray]:
        placement = self._placements.get(frame)  # tasks ask for it in error and Jacobian
        if placement is None:
            p_L, R_L = self._frames[frame]
            p = np.array([self.pose[0], self.pose[1], self._floor_z]) + self._R @ p_L
            placement = self._placements[frame] = (p, self._R @ R_L)
        return placement

    def frame_jacobian(self, frame: str) -> np.ndarray:
        """(6, 3): d/d(x, y, θ) of [position; angular velocity] in world."""
        p_L, _ = self._frames[frame]
        r = self._R @ p_L  # lever arm from the footprint
        J = np.zeros((6, 3))
        J[0, 0] = J[1, 1] = 1.0
        J[0, 2], J[1, 2] = -r[1], r[0]  # e_z × r
        J[5, 2] = 1.0
        return J


def prioritised_least_squares(
    levels, n: int, damping: float = 1e-4, rank_tolerance: float = 1e-7
) -> np.ndarray:
    """Strict hierarchy of unconstrained least-squares levels (A_i x = b_i), highest first:
    x = x_(i-1) + Z_(i-1) z_i with z_i the damped least-squares solution of level i in the null
    space Z_(i-1) of the levels above (Siciliano–Slotine). No bounds: the rigid-stance problem has
    none, so this is :func:`~marionette.footsteps.hierarchy.solve_hierarchy` without its QP
    machinery, at a fraction of its cost for 3 variables.

    ``levels``: an iterable of (A_i, b_i), consumed lazily: once the levels above leave no
    freedom the rest are not evaluated (the hand and gaze tasks take all 3 dofs of a stance)."""
    x = np.zeros(n)
    Z = None  # None: identity (no level yet)
    for A, b in levels:
        M = A if Z is None else A @ Z
        # One SVD M = U S Vᵀ gives both the damped least squares, (MᵀM + μI)⁻¹ Mᵀ r =
        # V diag(σ / (σ² + μ)) Uᵀ r, and the null space of M for the levels below.
        u, sv, vt = np.linalg.svd(M, full_matrices=True)
        p = sv.shape[0]
        z = vt[:p].T @ ((sv / (sv * sv + damping)) * (u[:, :p].T @ (b - A @ x)))
        x = x + (z if Z is None else Z @ z)
        rank = int(np.sum(sv > rank_tolerance * max(1.0, sv[0] if sv.size else 0.0)))
        if rank == M.shape[1]:
            break  # no freedom left for the levels below
        Z = vt[rank:].T if Z is None else Z @ vt[rank:].T
    return x


def solve_final_pose(
    tasks: list,
    pose0: np.ndarray,
    frames_L: dict,
    floor_z: float,
    tolerance: float = 1e-7,
    max_iterations: int = 30,
) -> tuple[np.ndarray, int]:
    """Gauss–Newton over the prioritised ``tasks`` (Task objects, highest first) in (x, y, θ).

    Returns (P_k*, iterations). The tasks' error clamps (``max_step``, meant for the long chain)
    are not applied: over 3 dofs of a rigid body, full Gauss–Newton steps converge in a few.
    """
    pose = np.asarray(pose0, dtype=float).copy()
    for iteration in range(1, max_iterations + 1):
        kin = RigidStanceKinematics(pose, frames_L, floor_z)
        levels = ((task.compute_jacobian(kin), -task.compute_error(kin)) for task in tasks)
        dx = prioritised_least_squares(levels, 3)
        pose += dx
        if np.max(np.abs(dx)) < tolerance:
            return pose, iteration
    return pose, max_iterations
