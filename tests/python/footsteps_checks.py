"""Independent checks of a footstep plan: geometry by sampling and scipy, not the optimiser's own
constraint code."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from marionette import robots
from marionette.footsteps.augmented_robot import rotation_2d
from marionette.footsteps.robot_model import FootShape

BALL = np.array([2.0, -0.2, 0.6])  # the grasp benchmark's ball: 2 m ahead, on a 0.6 m stand
# TALOS' foot as its footstep optimiser sees it, and its grasp point in gripper_<side>_base_link
# (the gripper frame's origin), both from models/talos/robot.yaml.
TALOS_FOOT = FootShape(*robots.robot("talos").walking["planning_foot_size"])
TALOS_GRASP_POINT = np.array(robots.semantics("talos").gripper("talos/right_gripper").pose.xyz)


def sole_points(pose: np.ndarray, foot: FootShape, n: int = 30) -> np.ndarray:
    """Points filling the sole rectangle at (x, y, yaw): (n², 2)."""
    u, v = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(-0.5, 0.5, n))
    local = np.column_stack([u.ravel() * foot.length, v.ravel() * foot.width])
    return pose[:2] + local @ rotation_2d(pose[2]).T


def soles_overlap(a: np.ndarray, b: np.ndarray, foot: FootShape) -> bool:
    """Does sole b (x, y, yaw) enter sole a? (dense sampling of b tested inside a)."""
    local = (sole_points(b, foot) - a[:2]) @ rotation_2d(a[2])
    inside = (np.abs(local[:, 0]) < 0.5 * foot.length) & (np.abs(local[:, 1]) < 0.5 * foot.width)
    return bool(np.any(inside))


def depth_inside_hull(point: np.ndarray, poses: list[np.ndarray], foot: FootShape) -> float:
    """Signed distance of ``point`` inside the convex hull of the soles (> 0 inside) [m]."""
    corners = np.vstack([sole_points(p, foot, 2) for p in poses])
    hull = ConvexHull(corners)
    # equations: n·x + c ≤ 0 inside, n unit outward normals.
    return float(-np.max(hull.equations[:, :2] @ point + hull.equations[:, 2]))


def step_variables_within(
    steps: np.ndarray, is_left: np.ndarray, limits, tol: float = 1e-6
) -> bool:
    lo, hi = limits.bounds(np.asarray(is_left), with_final=True)
    flat = steps.reshape(-1)
    return bool(np.all(flat >= lo - tol) and np.all(flat <= hi + tol))
