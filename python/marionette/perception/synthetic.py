"""Synthetic camera images with exact ground truth: planar textured rectangles (tags, cards,
walls) rendered by exact pinhole ray casting, anti-aliased by supersampling, with metric depth.

This is the independent reference of the perception tests and benchmark: a pixel's grey level is
the box-filtered coverage of the scene over the pixel footprint (``supersample`` x
``supersample`` rays per pixel), so tag corners land exactly where the pinhole model puts them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from marionette.models.apriltag import printed_size, tag_cells
from marionette.perception.camera import CameraIntrinsics


@dataclass(frozen=True)
class Quad:
    """A rectangle of the scene, centred on the origin of its frame S.

    ``X_CS`` places S in the camera (optical) frame. The rectangle spans ``width`` along x_S
    and ``height`` along y_S; ``texture`` (rows, cols) uint8 covers it with row 0 at +y_S and
    column 0 at -x_S (an image seen from +z_S, upright), or is one grey level.
    """

    X_CS: pin.SE3
    width: float  # [m]
    height: float  # [m]
    texture: np.ndarray | float = 255.0


@dataclass(frozen=True)
class SyntheticFrame:
    """A rendered frame: ``gray`` (h, w) uint8, ``rgb`` (h, w, 3) uint8 (grey replicated) and
    ``depth`` (h, w) float32, the z of the nearest surface at each pixel centre [m], 0 = none."""

    gray: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray


def tag_quad(tag_id: int, tag_size: float, X_CT: pin.SE3, margin_cells: int = 1) -> Quad:
    """The tag36h11 ``tag_id`` whose black square has edge ``tag_size`` [m], at pose ``X_CT``
    (tag frame of ``marionette._visp.tag_corners``: x right, y up, z out of the face), with its
    white border plus ``margin_cells`` cells of white paper around it."""
    if not tag_size > 0.0:
        raise ValueError(f"tag_size must be > 0, got {tag_size}")
    cells = tag_cells(tag_id)  # (10, 10) with the 1-cell white border, row 0 on top
    side = printed_size(tag_size) * (cells.shape[0] + 2 * margin_cells) / cells.shape[0]
    return Quad(X_CT, side, side, np.pad(cells, margin_cells, constant_values=255))


def _hit(quad: Quad, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth z (inf on a miss) and grey level of ``quad`` along (n, 3) rays (x, y, 1)."""
    R = quad.X_CS.rotation
    p0 = quad.X_CS.translation
    normal = R[:, 2]
    denom = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(np.abs(denom) > 1e-12, (normal @ p0) / denom, np.inf)
    z = np.where(z > 1e-6, z, np.inf)
    local = (rays * np.where(np.isfinite(z), z, 0.0)[:, None] - p0) @ R  # R^T (p - p0), rowwise
    qx, qy = local[:, 0], local[:, 1]
    inside = np.isfinite(z) & (np.abs(qx) <= quad.width / 2) & (np.abs(qy) <= quad.height / 2)
    z = np.where(inside, z, np.inf)
    if np.isscalar(quad.texture) or np.ndim(quad.texture) == 0:
        return z, np.full(z.shape, float(quad.texture))
    tex = np.asarray(quad.texture)
    rows, cols = tex.shape
    c = np.clip(((qx + quad.width / 2) / quad.width * cols).astype(int), 0, cols - 1)
    r = np.clip(((quad.height / 2 - qy) / quad.height * rows).astype(int), 0, rows - 1)
    return z, tex[r, c].astype(float)


def _cast(quads: Sequence[Quad], rays: np.ndarray, background: float, background_depth: float):
    z_best = np.full(rays.shape[0], background_depth if background_depth > 0.0 else np.inf)
    grey = np.full(rays.shape[0], float(background))
    for quad in quads:
        z, g = _hit(quad, rays)
        nearer = z < z_best
        z_best = np.where(nearer, z, z_best)
        grey = np.where(nearer, g, grey)
    return z_best, grey


def _image_box(intrinsics: CameraIntrinsics, quads: Sequence[Quad]) -> tuple[int, int, int, int]:
    """Pixel rectangle (u0, u1, v0, v1), end-exclusive, covering every quad's projection."""
    w, h = intrinsics.width, intrinsics.height
    u0, u1, v0, v1 = w, 0, h, 0
    for quad in quads:
        half = np.array([quad.width, quad.height]) / 2
        local = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]]) * np.r_[half, 0.0]
        p_C = (quad.X_CS.rotation @ local.T).T + quad.X_CS.translation
        if np.any(p_C[:, 2] <= 1e-6):
            return 0, w, 0, h  # crosses the camera plane: cast everywhere
        uv = intrinsics.project(p_C)
        u0, v0 = (
            min(u0, int(np.floor(uv[:, 0].min())) - 1),
            min(v0, int(np.floor(uv[:, 1].min())) - 1),
        )
        u1, v1 = (
            max(u1, int(np.ceil(uv[:, 0].max())) + 2),
            max(v1, int(np.ceil(uv[:, 1].max())) + 2),
        )
    return max(0, u0), min(w, u1), max(0, v0), min(h, v1)


def render(
    intrinsics: CameraIntrinsics,
    quads: Sequence[Quad],
    background: float = 128.0,
    background_depth: float = 0.0,
    supersample: int = 4,
    noise_std: float = 0.0,
    depth_noise_std: float = 0.0,
    rng: np.random.Generator | None = None,
    blur_px: float = 0.0,
) -> SyntheticFrame:
    """Renders ``quads`` (nearest surface wins) in front of a face-on background plane.

    Grey: mean of ``supersample**2`` rays spread uniformly over each pixel's square footprint,
    optionally blurred by a Gaussian of ``blur_px`` [px] (defocus), plus Gaussian noise
    ``noise_std`` [grey levels]. Depth: the surface hit by the ray through the pixel centre,
    plus Gaussian noise ``depth_noise_std`` [m]. The background has grey ``background`` and
    lies at z = ``background_depth`` (0: no depth return).
    """
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    rng = rng if rng is not None else np.random.default_rng(0)
    w, h, s = intrinsics.width, intrinsics.height, supersample
    gray = np.full((h, w), float(background))
    depth = np.full((h, w), max(0.0, background_depth))
    u0, u1, v0, v1 = _image_box(intrinsics, quads) if quads else (0, 0, 0, 0)
    if u1 > u0 and v1 > v0:
        offsets = (np.arange(s) + 0.5) / s - 0.5
        u = np.arange(u0, u1, dtype=float)
        bw = len(u)
        chunk = max(1, 400000 // (bw * s * s))  # rows per batch: bounded memory
        for r0 in range(v0, v1, chunk):
            v = np.arange(r0, min(v1, r0 + chunk), dtype=float)
            uu = u[None, :, None, None] + offsets[None, None, None, :]
            vv = v[:, None, None, None] + offsets[None, None, :, None]
            uu, vv = np.broadcast_arrays(uu, vv)
            rays = intrinsics.rays(uu.reshape(-1), vv.reshape(-1))
            _, g = _cast(quads, rays, background, background_depth)
            gray[r0 : r0 + len(v), u0:u1] = g.reshape(len(v), bw, s * s).mean(axis=2)
            centre = intrinsics.rays(*np.meshgrid(u, v))
            z, _ = _cast(quads, centre.reshape(-1, 3), background, background_depth)
            depth[r0 : r0 + len(v), u0:u1] = np.where(np.isfinite(z), z, 0.0).reshape(len(v), bw)
    if blur_px > 0.0:
        from scipy.ndimage import gaussian_filter

        gray = gaussian_filter(gray, blur_px, mode="nearest")
    if noise_std > 0.0:
        gray = gray + rng.normal(0.0, noise_std, gray.shape)
    if depth_noise_std > 0.0:
        depth = np.where(depth > 0.0, depth + rng.normal(0.0, depth_noise_std, depth.shape), 0.0)
    gray8 = np.clip(np.rint(gray), 0, 255).astype(np.uint8)
    return SyntheticFrame(gray8, np.repeat(gray8[:, :, None], 3, axis=2), depth.astype(np.float32))


def look_at(
    p_CT: ArrayLike, tilt_deg: float = 0.0, tilt_axis=(1.0, 0.0, 0.0), roll_deg: float = 0.0
) -> pin.SE3:
    """X_CT of a tag at ``p_CT`` facing the camera (z_T towards it, upright: y_T up in the image),
    then tilted by ``tilt_deg`` about ``tilt_axis`` (tag frame) and rolled by ``roll_deg`` about
    z_T."""
    R_facing = np.diag([1.0, -1.0, -1.0])  # x_T = x_C, y_T = -y_C (up), z_T = -z_C
    axis = np.asarray(tilt_axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    R = (
        R_facing
        @ pin.exp3(np.radians(tilt_deg) * axis)
        @ pin.exp3(np.radians(roll_deg) * np.array([0.0, 0.0, 1.0]))
    )
    return pin.SE3(R, np.asarray(p_CT, dtype=float))
