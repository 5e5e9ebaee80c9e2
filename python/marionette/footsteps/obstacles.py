"""Floor obstacles of the footstep optimiser: regions no sole may touch (Dang §3.2.2, fig. 3.4).

Each region carries its own buffer ("obstacles plus a buffer zone to assure some security"):
a sole must stay at least ``buffer`` away from it. A :class:`Bar` is a cylinder lying on the
floor (Dang ch. 5); its floor region is a rectangle of width 2·radius, and its height matters
for the swing foot (:mod:`marionette.footsteps.swing`, eq. 5.1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from marionette.footsteps.errors import InvalidProblem


def _xy(value, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=float).reshape(-1)
    if v.shape != (2,) or not np.all(np.isfinite(v)):
        raise InvalidProblem(f"{name} must be 2 finite numbers (x, y), got {value!r}")
    return v


@dataclass(frozen=True)
class CircleObstacle:
    """Disc of ``radius`` [m] centred at ``center`` (x, y) in world."""

    center: np.ndarray
    radius: float
    buffer: float = 0.03

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _xy(self.center, "CircleObstacle.center"))
        if not self.radius > 0.0 or not self.buffer >= 0.0:
            raise InvalidProblem(
                f"CircleObstacle needs radius > 0 and buffer >= 0, got {self.radius}, {self.buffer}"
            )


@dataclass(frozen=True)
class RectangleObstacle:
    """Rectangle centred at ``center`` (x, y), long side ``length`` along ``yaw`` [m, rad]."""

    center: np.ndarray
    yaw: float
    length: float
    width: float
    buffer: float = 0.03

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _xy(self.center, "RectangleObstacle.center"))
        if not (self.length > 0.0 and self.width > 0.0 and self.buffer >= 0.0):
            raise InvalidProblem(
                "RectangleObstacle needs length, width > 0 and buffer >= 0, "
                f"got {self.length}, {self.width}, {self.buffer}"
            )

    def axes(self) -> np.ndarray:
        """Unit axes (2, 2): row 0 along the length, row 1 along the width."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, s], [-s, c]])

    def corners(self) -> np.ndarray:
        """(4, 2) world corners."""
        u, v = self.axes()
        hl, hw = 0.5 * self.length, 0.5 * self.width
        return self.center + np.array(
            [hl * u + hw * v, -hl * u + hw * v, -hl * u - hw * v, hl * u - hw * v]
        )


@dataclass(frozen=True)
class Bar:
    """A cylinder lying on the floor (Dang ch. 5): axis along ``yaw`` through ``center``.

    ``radius`` [m]; ``length`` [m] along the axis. Its top is at 2·radius above the floor.
    """

    center: np.ndarray
    yaw: float
    radius: float
    length: float
    buffer: float = 0.03

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _xy(self.center, "Bar.center"))
        if not (self.radius > 0.0 and self.length > 0.0 and self.buffer >= 0.0):
            raise InvalidProblem(
                "Bar needs radius, length > 0 and buffer >= 0, got "
                f"{self.radius}, {self.length}, {self.buffer}"
            )

    def floor_region(self) -> RectangleObstacle:
        """The rectangle the bar covers on the floor."""
        return RectangleObstacle(self.center, self.yaw, self.length, 2.0 * self.radius, self.buffer)

    def normal(self) -> np.ndarray:
        """Unit floor direction across the bar (the walking direction over it)."""
        return np.array([-np.sin(self.yaw), np.cos(self.yaw)])

    def pose(self) -> np.ndarray:
        """(x, y, yaw) of the bar frame."""
        return np.array([self.center[0], self.center[1], self.yaw])

    def moved_to(self, center, yaw: float) -> Bar:
        return Bar(
            np.asarray(center, dtype=float), float(yaw), self.radius, self.length, self.buffer
        )


Obstacle = CircleObstacle | RectangleObstacle | Bar
