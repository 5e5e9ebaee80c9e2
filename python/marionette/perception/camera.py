"""Pinhole camera intrinsics, passed explicitly to every perception function."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics without distortion; pixel centres at integer coordinates.

    A point ``p_C = (x, y, z)`` of the optical frame (x right, y down, z forward) projects to
    ``u = fx x / z + cx`` (column) and ``v = fy y / z + cy`` (row, top row 0). Constructing an
    instance validates it: a ``ValueError`` names the bad field.
    """

    width: int  # [px]
    height: int  # [px]
    fx: float  # [px]
    fy: float  # [px]
    cx: float  # [px]
    cy: float  # [px]

    def __post_init__(self) -> None:
        if not (
            isinstance(self.width, (int, np.integer)) and isinstance(self.height, (int, np.integer))
        ):
            raise ValueError(f"image size must be integers, got {self.width!r} x {self.height!r}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image size must be positive, got {self.width} x {self.height}")
        for name in ("fx", "fy"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"focal length {name} must be finite and > 0, got {value}")
        for name in ("cx", "cy"):
            if not math.isfinite(float(getattr(self, name))):
                raise ValueError(
                    f"principal point {name} must be finite, got {getattr(self, name)}"
                )

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float) -> CameraIntrinsics:
        """Square pixels, centred principal point, vertical field of view ``fovy_deg`` (MuJoCo)."""
        if not 0.0 < fovy_deg < 180.0:
            raise ValueError(f"fovy must be in (0, 180) degrees, got {fovy_deg}")
        f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(width, height, f, f, 0.5 * (width - 1), 0.5 * (height - 1))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) calibration matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, p_C: np.ndarray) -> np.ndarray:
        """(n, 3) points in the optical frame -> (n, 2) pixels (u, v)."""
        p = np.atleast_2d(np.asarray(p_C, dtype=float))
        return np.column_stack(
            (self.fx * p[:, 0] / p[:, 2] + self.cx, self.fy * p[:, 1] / p[:, 2] + self.cy)
        )

    def rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Pixels -> (..., 3) rays (x, y, 1): the point at depth z along the ray is z * ray."""
        u = np.asarray(u, dtype=float)
        v = np.asarray(v, dtype=float)
        return np.stack(((u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u)), -1)

    @functools.cached_property
    def native(self):
        """The same intrinsics as ``marionette._visp.CameraIntrinsics`` (for the C++ library)."""
        from marionette import _visp

        return _visp.CameraIntrinsics(
            int(self.width),
            int(self.height),
            float(self.fx),
            float(self.fy),
            float(self.cx),
            float(self.cy),
        )
