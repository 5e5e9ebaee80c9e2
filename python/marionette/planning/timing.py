"""Time parameterisation of a plan's paths: each path at rest at its ends, a trapezoidal speed
profile along its arc length within the robots' joint velocity and acceleration limits (the
plan file's sample times, :func:`marionette.planning.path.save_plan`): a transition ends where
the controller switches."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

if TYPE_CHECKING:
    from marionette.planning.path import ConstrainedPath


@dataclasses.dataclass(frozen=True)
class Limits:
    """Per velocity-space coordinate bounds: ``velocity`` (nv) [rad/s or m/s] and
    ``acceleration`` (nv) [rad/s^2 or m/s^2]; inf where a coordinate is not limited."""

    velocity: np.ndarray
    acceleration: np.ndarray

    @classmethod
    def of_robots(cls, problem, acceleration: float = 2.0, velocity_scale: float = 1.0) -> Limits:
        """The robots' joint velocity limits (URDF) times ``velocity_scale`` and one
        ``acceleration`` for every robot joint; objects are not limited (they are carried)."""
        model = problem.model
        v = np.full(model.nv, np.inf)
        a = np.full(model.nv, np.inf)
        for j in problem.robot_joint_ids:
            iv, nv = model.idx_vs[j], model.joints[j].nv
            lim = np.asarray(model.velocityLimit[iv : iv + nv], dtype=float)
            lim = np.where((lim > 0) & np.isfinite(lim), lim, np.inf)
            v[iv : iv + nv] = lim * velocity_scale
            a[iv : iv + nv] = acceleration
        if not np.isfinite(v).any() and not np.isfinite(a).any():
            raise ValueError("no robot joint has a velocity or acceleration limit")
        return cls(v, a)


def _profile_time(s: np.ndarray, length: float, v: float, a: float) -> np.ndarray:
    """Times at arc lengths s of a rest-to-rest trapezoidal profile (cruise speed v, acceleration
    a) over [0, length]; triangular when the length is too short to reach v."""
    if length <= 0.0:
        return np.zeros_like(s)
    if not math.isfinite(v) and not math.isfinite(a):
        raise ValueError("a profile needs a finite speed or acceleration")
    if not math.isfinite(a):  # constant speed
        return s / v
    d_acc = v * v / (2 * a) if math.isfinite(v) else math.inf
    if 2 * d_acc >= length:  # triangle: accelerate to the middle, then brake
        half = length / 2
        t_half = math.sqrt(2 * half / a)
        return np.where(
            s <= half,
            np.sqrt(2 * np.maximum(s, 0.0) / a),
            2 * t_half - np.sqrt(2 * np.maximum(length - s, 0.0) / a),
        )
    t_acc = v / a
    t_cruise = (length - 2 * d_acc) / v
    total = 2 * t_acc + t_cruise
    return np.where(
        s <= d_acc,
        np.sqrt(2 * np.maximum(s, 0.0) / a),
        np.where(
            s <= length - d_acc,
            t_acc + (s - d_acc) / v,
            total - np.sqrt(2 * np.maximum(length - s, 0.0) / a),
        ),
    )


def path_speed_limits(path: ConstrainedPath, limits: Limits) -> tuple[float, float]:
    """(largest arc-length speed, largest arc-length acceleration) that keep every joint of the
    path within ``limits``: |dq_j/ds| |ds/dt| <= v_j, |dq_j/ds| |d2s/dt2| <= a_j, taken over
    every segment of the path's polyline (arc length = the path's |v| metric over its free
    variables; substituted objects move with their parents)."""
    model = path.model
    v_s, a_s = math.inf, math.inf
    for a, b, ds in zip(path.points, path.points[1:], np.diff(path.cum)):
        if ds <= 0.0:
            continue
        tangent = np.abs(pin.difference(model, a, b)) / ds  # |dq/ds| per coordinate
        with np.errstate(divide="ignore"):
            v_s = min(v_s, float(np.min(limits.velocity / tangent)))
            a_s = min(a_s, float(np.min(limits.acceleration / tangent)))
    return v_s, a_s


def time_parameterize(
    paths: Sequence[ConstrainedPath], limits: Limits, samples: Sequence[np.ndarray]
) -> tuple[list[np.ndarray], list[float]]:
    """Times of the given arc-length samples of each path (``samples[i]``: increasing, in
    [0, paths[i].length]) under ``limits``, each path at rest at its ends, and the durations.
    Times are absolute: each path starts when the previous one ends."""
    times, durations = [], []
    t0 = 0.0
    for p, s in zip(paths, samples):
        v_s, a_s = path_speed_limits(p, limits)
        if p.length <= 0.0:
            t = np.zeros(len(s))
            duration = 0.0
        else:
            t = _profile_time(np.asarray(s, dtype=float), p.length, v_s, a_s)
            duration = float(_profile_time(np.array([p.length]), p.length, v_s, a_s)[0])
        times.append(t0 + t)
        durations.append(duration)
        t0 += duration
    return times, durations
