"""Top views of footstep plans (Dang fig. 3.5 / 6.2): soles, obstacles with their buffers, goal,
hand target, and optionally earlier plans to show the deformation."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from marionette.footsteps.obstacles import Bar, CircleObstacle, Obstacle, RectangleObstacle
from marionette.footsteps.plan import FootstepPlan
from marionette.footsteps.robot_model import FootShape

LEFT_COLOR, RIGHT_COLOR = "tab:blue", "tab:red"


def _sole_outline(pose: np.ndarray, foot: FootShape) -> np.ndarray:
    c, s = np.cos(pose[3]), np.sin(pose[3])
    R = np.array([[c, -s], [s, c]])
    corners = foot.corners() @ R.T + pose[:2]
    return np.vstack([corners, corners[:1]])


def _draw_plan(ax, plan: FootstepPlan, foot: FootShape, alpha: float, numbers: bool) -> None:
    for _side, pose in plan.stance.items():
        outline = _sole_outline(pose, foot)
        ax.fill(outline[:, 0], outline[:, 1], color="0.8", alpha=alpha, lw=0)
        ax.plot(outline[:, 0], outline[:, 1], color="0.4", lw=1.0, alpha=alpha)
    for step in plan.steps:
        color = LEFT_COLOR if step.is_left else RIGHT_COLOR
        outline = _sole_outline(step.pose, foot)
        ax.plot(outline[:, 0], outline[:, 1], color=color, lw=1.2, alpha=alpha)
        if numbers:
            ax.annotate(
                str(step.index),
                step.pose[:2],
                ha="center",
                va="center",
                fontsize=7,
                color=color,
                alpha=alpha,
            )
        if step.via.shape[0]:
            ax.plot(step.via[:, 0], step.via[:, 1], "x", color=color, ms=4, alpha=alpha)


def _draw_obstacle(ax, obstacle: Obstacle) -> None:
    import matplotlib.patches as patches

    if isinstance(obstacle, CircleObstacle):
        center = (float(obstacle.center[0]), float(obstacle.center[1]))
        ax.add_patch(patches.Circle(center, obstacle.radius, color="0.3"))
        ax.add_patch(
            patches.Circle(
                center, obstacle.radius + obstacle.buffer, fill=False, ls="--", color="0.3"
            )
        )
        return
    region = obstacle.floor_region() if isinstance(obstacle, Bar) else obstacle
    corners = np.vstack([region.corners(), region.corners()[:1]])
    ax.fill(
        corners[:, 0], corners[:, 1], color="tab:orange" if isinstance(obstacle, Bar) else "0.3"
    )
    grown = RectangleObstacle(
        region.center,
        region.yaw,
        region.length + 2 * region.buffer,
        region.width + 2 * region.buffer,
    )
    g = np.vstack([grown.corners(), grown.corners()[:1]])
    ax.plot(g[:, 0], g[:, 1], "--", color="0.3", lw=0.8)


def plot_plan(
    path: str | Path,
    plan: FootstepPlan,
    foot: FootShape,
    obstacles: Sequence[Obstacle] = (),
    goal: np.ndarray | None = None,
    hand_target: np.ndarray | None = None,
    earlier: Sequence[FootstepPlan] = (),
    title: str = "",
) -> Path:
    """Write a PNG top view of ``plan`` (and faded ``earlier`` plans) to ``path``.

    ``goal``: (x, y[, yaw]) of the final stance; ``hand_target``: (x, y[, z]) of the object.
    Left soles blue, right soles red, initial stance grey, swing passage points as crosses,
    obstacles dark with their buffer dashed (a bar in orange).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5), dpi=120)
    for obstacle in obstacles:
        _draw_obstacle(ax, obstacle)
    for i, old in enumerate(earlier):
        _draw_plan(ax, old, foot, alpha=0.25 + 0.3 * i / max(len(earlier), 1), numbers=False)
    _draw_plan(ax, plan, foot, alpha=1.0, numbers=True)
    if goal is not None:
        goal = np.asarray(goal, dtype=float)
        ax.plot(goal[0], goal[1], "k+", ms=12, mew=2, label="goal")
        if goal.shape[0] > 2:
            ax.arrow(
                goal[0],
                goal[1],
                0.1 * np.cos(goal[2]),
                0.1 * np.sin(goal[2]),
                head_width=0.02,
                color="k",
            )
    if hand_target is not None:
        ax.plot(hand_target[0], hand_target[1], "*", color="tab:green", ms=14, label="hand target")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title)
    if goal is not None or hand_target is not None:
        ax.legend(loc="best", fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
