"""Swing-foot passage points over a bar (Dang ch. 5, eq. 5.1).

Cross-section of the crossing: s is the horizontal coordinate across the bar (along its floor
normal, from the lift-off side), h the height above the floor. The bar is a disc of radius R
centred at (s_c, h_c) (h_c = R for a bar lying on the floor), completed downwards to the floor:
Dang's eq. 5.2 "mountain" class, for which checking the flat sole suffices. The sole is the
segment [s − d1, s + d2] at height h around its operational point O (d1 to the heel, d2 to the
toe; the foot is parallel to the floor during the swing). The sole is collision free iff
(eq. 5.1):

    toe before the bar's axis (s + d2 < s_c):   (s + d2 − s_c)² + (h − h_c)² ≥ R²  (h ≥ h_c)
                                                 |s + d2 − s_c| ≥ R                 (h < h_c)
    heel past the bar's axis (s − d1 > s_c):    the same with s − d1
    otherwise (the sole spans the axis):         h − h_c ≥ R

(The thesis writes the case boundaries as s ≤ s_c − R − d2 and s ≥ s_c + R + d1; with those,
its first and last lines hold trivially and the region between is over-constrained. The
boundaries above are the ones under which the three lines describe the Minkowski sum of the
sole and the obstacle.)
"""

from __future__ import annotations

import numpy as np

from marionette.footsteps.errors import InvalidProblem
from marionette.footsteps.obstacles import Bar


def bar_clearance(
    s: np.ndarray, h: np.ndarray, s_c: float, h_c: float, radius: float, d1: float, d2: float
) -> np.ndarray:
    """Signed clearance of eq. 5.1 for sole points O = (s, h) (any shape): ≥ 0 is collision free.

    Lengths in metres. Where the sole spans the bar's axis the value is the height margin
    h − h_c − R; elsewhere it is the distance from the leading/trailing sole end to the bar's
    cross-section minus R.
    """
    s = np.asarray(s, dtype=float)
    h = np.asarray(h, dtype=float)
    toe, heel = s + d2 - s_c, s - d1 - s_c
    dh = h - h_c

    def end_clearance(ds):
        return np.where(dh >= 0.0, np.hypot(ds, dh), np.abs(ds)) - radius

    return np.where(
        toe < 0.0, end_clearance(toe), np.where(heel > 0.0, end_clearance(heel), dh - radius)
    )


def sole_extent_across(bar: Bar, yaw: float, length: float, width: float) -> float:
    """Half extent of a sole of yaw ``yaw`` along the bar's floor normal [m] (d1 = d2)."""
    phi = yaw - (bar.yaw + 0.5 * np.pi)  # angle between the sole's x and the bar normal
    return 0.5 * length * abs(np.cos(phi)) + 0.5 * width * abs(np.sin(phi))


def crossing_via_points(
    lift_off: np.ndarray,
    landing: np.ndarray,
    bar: Bar,
    length: float,
    width: float,
    margin: float = 0.03,
) -> tuple[np.ndarray, float]:
    """Two passage points of the sole centre over ``bar`` and the swing apex height.

    ``lift_off``/``landing``: (x, y, z, yaw) of the sole on either side of the bar [m, rad].
    Returns (via (2, 3) world points, apex height above the floor). The polyline lift-off →
    via₁ → via₂ → landing keeps eq. 5.1's clearance ≥ ``margin`` wherever the sole is within
    the bar's band: via₁ and via₂ sit ``margin`` beyond the band widened by the sole's half
    extent (less if a footprint is nearer), at height 2R + margin (h_c + R + margin).
    """
    lift_off = np.asarray(lift_off, dtype=float)
    landing = np.asarray(landing, dtype=float)
    n = bar.normal()
    s0 = float(n @ (lift_off[:2] - bar.center))
    s1 = float(n @ (landing[:2] - bar.center))
    if s0 * s1 >= 0.0:
        raise InvalidProblem("lift-off and landing are on the same side of the bar")
    direction = np.sign(s1 - s0)  # walk along +n or −n
    d = max(
        sole_extent_across(bar, lift_off[3], length, width),
        sole_extent_across(bar, landing[3], length, width),
    )
    floor_z = lift_off[2]
    apex = 2.0 * bar.radius + margin  # h_c + R + margin with h_c = R
    vias = []
    for side, s_end in ((-1.0, s0), (1.0, s1)):
        # ``margin`` beyond the band, but never beyond the footprint itself.
        room = max(abs(s_end) - bar.radius - d, 0.0)
        s_via = direction * side * (bar.radius + d + min(margin, room))
        # Lateral position (along the bar) interpolated between lift-off and landing.
        t = (s_via - s0) / (s1 - s0)
        p = lift_off[:2] + t * (landing[:2] - lift_off[:2])
        p = p + (s_via - float(n @ (p - bar.center))) * n
        vias.append([p[0], p[1], floor_z + apex])
    return np.array(vias), apex
