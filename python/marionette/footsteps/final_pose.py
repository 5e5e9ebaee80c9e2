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
from marionette.footsteps.hierarchy import HierarchySettings, Level, solve_hierarchy


class RigidStanceKinematics:
    """Robot frames of a frozen posture standing on footprint ``pose`` (x, y, θ)."""

    k = 1
    robot_free = False
    nv = 3

    def __init__(self, pose: np.ndarray, frames_L: dict, floor_z: float) -> None:
        self.pose = np.asarray(pose, dtype=float)
        self._frames = frames_L            # name -> (p_L (3,), R_L (3, 3))
        self._floor_z = floor_z
        self._R = rotation_z(self.pose[2])

    def footprint(self, i: int) -> np.ndarray:
        return self.pose

    def footprint_jacobian(self, i: int) -> np.ndarray:
        return np.eye(3)

    def frame_placement(self, frame: str) -> tuple[np.ndarray, np.ndarray]:
        p_L, R_L = self._frames[frame]
        p = np.array([self.pose[0], self.pose[1], self._floor_z]) + self._R @ p_L
        return p, self._R @ R_L

    def frame_jacobian(self, frame: str) -> np.ndarray:
        """(6, 3): d/d(x, y, θ) of [position; angular velocity] in world."""
        p_L, _ = self._frames[frame]
        r = self._R @ p_L                                  # lever arm from the footprint
        J = np.zeros((6, 3))
        J[0, 0] = J[1, 1] = 1.0
        J[0, 2], J[1, 2] = -r[1], r[0]                     # e_z × r
        J[5, 2] = 1.0
        return J


def solve_final_pose(tasks: list, pose0: np.ndarray, frames_L: dict, floor_z: float,
                     tolerance: float = 1e-7, max_iterations: int = 30,
                     settings: HierarchySettings | None = None) -> tuple[np.ndarray, int]:
    """Gauss–Newton over the prioritised ``tasks`` (Task objects, highest first) in (x, y, θ).

    Returns (P_k*, iterations). The tasks' error clamps (``max_step``, meant for the long chain)
    are not applied: over 3 dofs of a rigid body, full Gauss–Newton steps converge in a few.
    """
    pose = np.asarray(pose0, dtype=float).copy()
    unbounded = np.full(3, np.inf)
    for iteration in range(1, max_iterations + 1):
        kin = RigidStanceKinematics(pose, frames_L, floor_z)
        levels = []
        for task in tasks:
            e = task.compute_error(kin)
            levels.append(Level.task(task.name, task.compute_jacobian(kin), e))
        dx = solve_hierarchy(levels, -unbounded, unbounded, settings).x
        pose += dx
        if np.max(np.abs(dx)) < tolerance:
            return pose, iteration
    return pose, max_iterations
