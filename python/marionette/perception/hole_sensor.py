"""A tool's hole sensor (thesis 000 §6.2-6.3): laser range-finders give the skin's plane, a camera
on the tool finds a hole's centre on that plane - "a matter of trigonometry".

Everything is expressed in one frame F that the caller gives the beams and the camera in (the
tool frame of the drilling spindle): no pose of the part or of the tool in the world enters, so
the measurement is what the sensors on the tool see, whatever the arm's kinematics get wrong.

* :func:`skin_plane`: the plane through the points the beams hit (three beams: exact; more:
  least squares), its normal turned towards the sensors.
* :func:`find_hole`: each pixel near where the hole is expected is cast onto that plane, the dark
  disc is segmented (Otsu's threshold, the connected region nearest the expectation) and its
  centre is the *area* centroid on the plane, each pixel weighted by its darkness (the fraction
  of it the hole covers) times the area it sees on the plane. The centroid of the disc's image
  would be off the centre's image under perspective (by ~0.1 mm for a 4 mm hole seen at 45 deg
  from 11 cm); the centroid on the plane is not.

A hole the sensor cannot measure raises :class:`HoleNotSeen` with the reason (beam off the part,
hole outside the image, nothing dark where expected, a dark region that is not a hole's size):
the thesis's "impossibility to detect the reference holes", which asks for an operator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy import ndimage

from marionette.perception.camera import CameraIntrinsics


class HoleNotSeen(RuntimeError):
    """The sensor cannot measure the hole; the message says why."""


@dataclass(frozen=True)
class Plane:
    """A plane of frame F: ``normal`` (unit, towards the sensors) and one ``point`` of it."""

    normal: np.ndarray
    point: np.ndarray
    rms_m: float  # the beams' points off the fitted plane (0 with three beams) [m]

    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """Two unit vectors spanning the plane (with ``normal``: a right-handed frame)."""
        n = self.normal
        e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(n, e1)

    def intersect(self, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(..., 3) points where the rays ``origin + t d`` (t > 0) meet the plane; NaN where a
        ray is parallel to it or meets it behind the origin."""
        d = np.asarray(directions, dtype=float)
        dn = d @ self.normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((self.point - origin) @ self.normal) / dn
        t = np.where((np.abs(dn) > 1e-9) & (t > 0.0), t, np.nan)
        return origin + t[..., None] * d


@dataclass(frozen=True)
class HoleMeasurement:
    """A hole measured in frame F: its centre on the skin, the skin's normal there (towards the
    sensors), the dark area found [m^2] and how far the centre is from where it was expected."""

    centre: np.ndarray
    normal: np.ndarray
    area_m2: float
    pixels: int
    offset_m: float

    def pose(self) -> pin.SE3:
        """X_F_hole: origin at the centre, x axis into the hole (-normal), the rotation about it
        the smallest one from F's own x axis (the tool axis; free for a hole)."""
        return pin.SE3(axis_rotation(-self.normal), self.centre.copy())


def axis_rotation(a: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the x axis onto the unit vector ``a``."""
    x = np.array([1.0, 0.0, 0.0])
    v = np.cross(x, a)
    s, c = float(np.linalg.norm(v)), float(np.dot(x, a))
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([-1.0, -1.0, 1.0])
    return pin.exp3(v / s * np.arctan2(s, c))


def skin_plane(origins: np.ndarray, directions: np.ndarray, distances: np.ndarray) -> Plane:
    """The plane through the points the beams hit: beam i leaves ``origins[i]`` along the unit
    ``directions[i]`` and measures ``distances[i]`` [m] (negative: nothing hit, MuJoCo's -1)."""
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    d = np.asarray(distances, dtype=float).reshape(-1)
    if not (len(o) == len(u) == len(d)):
        raise ValueError(f"{len(o)} beam origins, {len(u)} directions, {len(d)} distances")
    if len(d) < 3:
        raise HoleNotSeen(f"{len(d)} range finders: a plane needs three")
    missed = [i for i, r in enumerate(d) if not (np.isfinite(r) and r >= 0.0)]
    if missed:
        raise HoleNotSeen(
            f"range finder{'s' if len(missed) > 1 else ''} {', '.join(map(str, missed))} "
            "hit nothing: the skin is out of the lasers' reach"
        )
    points = o + d[:, None] * (u / np.linalg.norm(u, axis=1, keepdims=True))
    centre = points.mean(axis=0)
    _, s, vt = np.linalg.svd(points - centre)
    if s[1] < 1e-6 * max(s[0], 1e-12):
        raise HoleNotSeen("the range finders' points are in a line: no plane")
    n = vt[2]
    if np.dot(n, u.sum(axis=0)) > 0.0:  # towards the sensors: against the beams
        n = -n
    rms = float(np.sqrt(np.mean(((points - centre) @ n) ** 2)))
    return Plane(n, centre, rms)


def otsu_threshold(values: np.ndarray) -> float:
    """Otsu's threshold of grey values (the one that maximises the between-class variance)."""
    v = np.sort(np.asarray(values, dtype=float).ravel())
    if v.size < 2 or v[0] == v[-1]:
        return float(v[0]) if v.size else 0.0
    k = np.arange(1, v.size)  # class 0 = v[:k]
    c = np.cumsum(v)
    m0 = c[:-1] / k
    m1 = (c[-1] - c[:-1]) / (v.size - k)
    between = k * (v.size - k) * (m0 - m1) ** 2
    between[v[1:] == v[:-1]] = -1.0  # a threshold must fall between two different values
    i = int(np.argmax(between))
    return 0.5 * (v[i] + v[i + 1])


def find_hole(
    gray: np.ndarray,
    K: CameraIntrinsics,
    X_FC: pin.SE3,
    plane: Plane,
    expected: np.ndarray,
    hole_radius: float,
    search_radius: float,
    area_tolerance: float = 0.35,
) -> HoleMeasurement:
    """The dark disc of radius ``hole_radius`` [m] on ``plane`` nearest ``expected`` (frame F),
    searched within ``search_radius`` [m] of it, in the grey image ``gray`` (rows top first) of the
    camera whose optical frame is ``X_FC`` (x right, y down, z along the view).

    Raises :class:`HoleNotSeen` when the search disc leaves the image, nothing dark lies in it,
    the dark region reaches the search disc's edge (the hole is not where expected, or the
    expectation is too poor for ``search_radius``), or its area is not a hole's within
    ``area_tolerance`` (relative)."""
    if search_radius <= hole_radius:
        raise ValueError(f"search radius {search_radius} m must exceed the hole's {hole_radius} m")
    gray = np.asarray(gray, dtype=float)
    e1, e2 = plane.basis()
    c = np.asarray(expected, dtype=float)
    c = c - np.dot(c - plane.point, plane.normal) * plane.normal  # onto the plane
    # The search disc in the image: its rim projected; all of it must be in view.
    phi = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    rim_F = c + search_radius * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    rim_C = (X_FC.inverse().rotation @ rim_F.T).T + X_FC.inverse().translation
    if np.any(rim_C[:, 2] <= 0.0):
        raise HoleNotSeen("the hole is behind the camera")
    uv = K.project(rim_C)
    if (
        uv[:, 0].min() < 0.5
        or uv[:, 1].min() < 0.5
        or uv[:, 0].max() > K.width - 1.5
        or uv[:, 1].max() > K.height - 1.5
    ):
        raise HoleNotSeen(
            f"the skin within {search_radius * 1e3:.0f} mm of the expected hole is not all in the "
            "camera's view"
        )
    u0, v0 = np.floor(uv.min(axis=0)).astype(int)
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int)
    roi = gray[v0 : v1 + 1, u0 : u1 + 1]

    def on_plane(du: float, dv: float) -> np.ndarray:
        """(rows, cols, 2) plane coordinates about ``c`` of the ROI's pixels shifted (du, dv)."""
        u, v = np.meshgrid(np.arange(u0, u1 + 1) + du, np.arange(v0, v1 + 1) + dv)
        rays = X_FC.rotation @ K.rays(u, v).reshape(-1, 3).T
        p = plane.intersect(X_FC.translation, rays.T) - c
        return np.stack((p @ e1, p @ e2), -1).reshape(*u.shape, 2)

    q = on_plane(0.0, 0.0)
    # Each pixel's footprint on the plane (the area it sees): |dq/du x dq/dv|.
    qu = on_plane(0.5, 0.0) - on_plane(-0.5, 0.0)
    qv = on_plane(0.0, 0.5) - on_plane(0.0, -0.5)
    footprint = np.abs(qu[..., 0] * qv[..., 1] - qu[..., 1] * qv[..., 0])
    r = np.hypot(q[..., 0], q[..., 1])
    inside = np.isfinite(r) & (r < search_radius)
    threshold = otsu_threshold(roi[inside])
    dark = inside & (roi < threshold)
    regions, count = ndimage.label(dark)
    if count == 0:
        raise HoleNotSeen(f"nothing dark within {search_radius * 1e3:.0f} mm of the expected hole")
    # The region whose own centroid is nearest the expectation.
    index = np.arange(1, count + 1)
    mean_q = np.stack(
        [ndimage.mean(q[..., k], regions, index) for k in range(2)], axis=-1
    )  # (count, 2)
    best = int(index[np.argmin(np.hypot(mean_q[:, 0], mean_q[:, 1]))])
    region = regions == best
    if r[region].max() > search_radius - 2.0 * np.sqrt(footprint[region].max()):
        raise HoleNotSeen(
            f"the dark region nearest the expected hole reaches {search_radius * 1e3:.0f} mm "
            "from it: the hole is not where expected"
        )
    hole_level = float(np.median(roi[region]))
    skin_level = float(np.median(roi[inside & ~dark]))
    if skin_level - hole_level <= 0.0:
        raise HoleNotSeen("no contrast between the hole and the skin around it")
    # Darkness = the fraction of the pixel the hole covers (edges are blended), within two
    # pixels of the region (the blended rim); 0 on the skin.
    rim = ndimage.binary_dilation(region, iterations=2) & inside
    w = np.where(rim, np.clip((skin_level - roi) / (skin_level - hole_level), 0.0, 1.0), 0.0)
    wa = w * footprint
    area = float(wa.sum())
    centre_q = (wa[..., None] * np.nan_to_num(q)).sum(axis=(0, 1)) / area
    expected_area = np.pi * hole_radius**2
    if abs(area / expected_area - 1.0) > area_tolerance:
        raise HoleNotSeen(
            f"the dark region nearest the expected hole covers {area * 1e6:.1f} mm^2, a hole "
            f"{expected_area * 1e6:.1f} mm^2: not a hole seen whole"
        )
    centre = c + centre_q[0] * e1 + centre_q[1] * e2
    return HoleMeasurement(
        centre=centre,
        normal=plane.normal.copy(),
        area_m2=area,
        pixels=int(region.sum()),
        offset_m=float(np.linalg.norm(centre - np.asarray(expected, dtype=float))),
    )
