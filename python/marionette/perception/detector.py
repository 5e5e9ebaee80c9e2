"""AprilTag detection with both planar pose hypotheses and their resolution (thesis 000 §5.2.1).

A planar square seen by a pinhole camera has two poses that explain its four corners almost
equally well when it is small, far or seen nearly face-on (fig. 5.1): a tilt ``+a`` and a tilt
``-a`` about an axis of the tag plane. ``AprilTagDetector.detect`` keeps both, ranks them by
reprojection error, and decides:

1. ``"image"``: the runner-up's error is clearly larger (ratio test, as WPILib's "ambiguity"
   < 0.2) and above the corner-noise floor: the smaller error wins;
2. ``"depth"``: otherwise, with an aligned depth map, ViSP's RGB-D planar pose (plane fitted to
   the depth inside the tag, the thesis's colleague's method, merged into ViSP) picks the
   hypothesis whose normal is closest to the measured surface's;
3. ``"prior"``: otherwise a prior (e.g. the graph state says the object lies on the table)
   scores each hypothesis; the lower cost wins if the two costs differ clearly;
4. otherwise the smaller error is kept and ``ambiguous`` stays set.

With depth, the retained hypothesis is then refined on corners *and* depth pixels together
(``marionette._visp.refine_pose_rgbd``): the tilt of a small tag seen face-on, which its corners
barely constrain, comes from the depth plane. ``X_CT`` is that fused pose; ``hypotheses`` stay
the image-only minima.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from marionette.perception.camera import CameraIntrinsics

# prior(tag_id, X_CT) -> cost [rad] of that hypothesis (lower is more plausible), or None when
# the prior says nothing about that tag.
HypothesisPrior = Callable[[int, pin.SE3], "float | None"]


@dataclass(frozen=True)
class TagDetection:
    """One tag in one image, poses in the camera's optical frame C (x right, y down, z ahead).

    ``hypotheses[0]`` has the smaller reprojection error; ``chosen`` indexes the retained one.
    The tag frame T: origin at the centre of the black square, x right and y up when the tag is
    upright, z out of the printed face (``marionette._visp.tag_corners`` gives its corners).
    """

    tag_id: int
    corners: np.ndarray  # (4, 2) pixels (u, v), order of tag_corners()
    tag_size: float  # [m], edge of the black square
    hypotheses: tuple[pin.SE3, pin.SE3]  # X_CT candidates; the same twice when no second exists
    reprojection_errors: tuple[float, float]  # sum of squared corner distances [px^2]
    has_second: bool
    chosen: int
    ambiguous: bool
    resolved_by: str  # "image" | "depth" | "prior"
    X_CT_depth: pin.SE3 | None = None  # the retained hypothesis refined with depth, if any

    @property
    def X_CT(self) -> pin.SE3:
        """Camera <- tag: the retained hypothesis (refined with depth when there was depth)."""
        return self.X_CT_depth if self.X_CT_depth is not None else self.hypotheses[self.chosen]

    @property
    def X_CT_alternative(self) -> pin.SE3:
        return self.hypotheses[1 - self.chosen]


@dataclass
class DetectorConfig:
    """Tag sizes and decision thresholds of :class:`AprilTagDetector`."""

    tag_sizes: Mapping[int, float] = field(default_factory=dict)  # black-square edge per id [m]
    default_size: float = 0.0  # for ids not listed; <= 0: such tags get no pose and are dropped
    ambiguity_ratio: float = 0.2  # ambiguous when error_best / error_other exceeds this
    corner_noise_px: float = 0.3  # below 4 * noise^2 px^2 the runner-up is as good as the best
    prior_margin_rad: float = math.radians(10.0)  # a prior decides only past this cost gap
    refine_with_depth: bool = True  # fuse the depth plane into the retained pose
    # Depth noise [m] the RGB-D fusion starts from; it then weights the depth with the noise its
    # residuals show (planar_pose.h, RefinePoseRgbd), so this is a first guess, not a promise.
    depth_sigma: float = 0.003
    # Depth pixels used: the black square's corner polygon scaled by this about its centre;
    # the white border reaches 1.25 (10 / 8 cells), 1.1 keeps a margin from the tag's edge.
    depth_polygon_scale: float = 1.1
    quad_decimate: float = (
        2.0  # AprilTag's default: quads on a half-size image, edges refined at full size
    )
    quad_sigma: float = 0.0  # blur [px] before quad detection (at least this much)
    # Blur for quad detection chosen per image from its measured pixel noise (sensor noise
    # multiplies AprilTag's segmentation work ~10x; see marionette._visp.blur_for_noise).
    noise_adaptive_blur: bool = True
    num_threads: int = 1


def errors_ambiguous(
    best: float, other: float, num_corners: int, ratio: float, corner_noise_px: float
) -> bool:
    """Whether a runner-up local minimum (sum of squared errors ``other`` [px^2]) explains
    ``num_corners`` corners about as well as the best (``best``): within the ratio test, or
    under the error that corner noise alone would produce."""
    return other <= num_corners * corner_noise_px**2 or best > ratio * other


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle [rad] of the rotation R_a^T R_b."""
    return float(np.linalg.norm(pin.log3(R_a.T @ R_b)))


class AprilTagDetector:
    """tag36h11 detection + pose (ViSP 3.5 through ``marionette._visp``), one per thread."""

    def __init__(self, config: DetectorConfig | None = None) -> None:
        from marionette import _visp

        self.config = config or DetectorConfig()
        for tag_id, size in self.config.tag_sizes.items():
            if not (math.isfinite(size) and size > 0.0):
                raise ValueError(f"tag {tag_id}: size must be finite and > 0 m, got {size}")
        if not 0.0 < self.config.ambiguity_ratio < 1.0:
            raise ValueError(
                f"ambiguity_ratio must be in (0, 1), got {self.config.ambiguity_ratio}"
            )
        self._visp = _visp
        if not self.config.quad_sigma >= 0.0:
            raise ValueError(f"quad_sigma must be >= 0 px, got {self.config.quad_sigma}")
        self._native = _visp.AprilTagDetector(
            quad_decimate=self.config.quad_decimate,
            quad_sigma=self.config.quad_sigma,
            num_threads=self.config.num_threads,
            noise_adaptive_blur=self.config.noise_adaptive_blur,
        )
        self._sizes = {int(k): float(v) for k, v in self.config.tag_sizes.items()}

    def detect(
        self,
        gray: np.ndarray,
        intrinsics: CameraIntrinsics,
        depth: np.ndarray | None = None,
        prior: HypothesisPrior | None = None,
        regions: Sequence[tuple[int, int, int, int]] | None = None,
    ) -> list[TagDetection]:
        """Tags with a known size in ``gray`` (h, w) uint8; ``depth`` (h, w) [m] is optional.

        ``regions``: search only these ``(u0, v0, u1, v1)`` pixel boxes (columns u0..u1-1, rows
        v0..v1-1; a tag's white border must lie inside one), e.g. from a
        :class:`~marionette.perception.tracking.TagRegionTracker`; None: the whole image.

        Raises ``ValueError`` when the image or depth shape disagrees with the intrinsics.
        """
        gray = np.asarray(gray)
        if gray.dtype != np.uint8 or gray.ndim != 2:
            raise ValueError(f"gray must be a (h, w) uint8 image, got {gray.dtype} {gray.shape}")
        if depth is not None:
            depth = np.asarray(depth, dtype=np.float32)
            if depth.shape != gray.shape:
                raise ValueError(f"depth {depth.shape} and image {gray.shape} differ in shape")
        native = self._native.detect(
            np.ascontiguousarray(gray),
            intrinsics.native,
            self._sizes,
            self.config.default_size,
            [] if regions is None else [tuple(map(int, r)) for r in regions],
        )
        out = []
        for d in native:
            if not d.has_pose:
                continue
            hyps = tuple(pin.SE3(h.X_CT) for h in d.hypotheses)
            errors = tuple(float(h.reprojection_error) for h in d.hypotheses)
            out.append(self._decide(d, hyps, errors, intrinsics, depth, prior))
        return out

    @property
    def last_stats(self):
        """What the last :meth:`detect` did: ``noise_sigma`` [grey levels], ``quad_sigma`` [px],
        ``pixels_searched``."""
        return self._native.last_stats

    def is_ambiguous(self, errors: tuple[float, float], has_second: bool) -> bool:
        """The runner-up explains the corners about as well as the best (see module doc)."""
        if not has_second:
            return False
        return errors_ambiguous(
            *errors, 4, self.config.ambiguity_ratio, self.config.corner_noise_px
        )

    def _decide(self, d, hyps, errors, intrinsics, depth, prior) -> TagDetection:
        ambiguous = self.is_ambiguous(errors, d.has_second)
        chosen, resolved_by = 0, "image"
        if ambiguous and depth is not None:
            rgbd = self._visp.pose_from_rgbd(
                depth, intrinsics.native, d.corners, self._visp.tag_corners(d.tag_size)
            )
            if rgbd.ok:
                # Thesis: keep the hypothesis whose normal is closest to the depth surface's.
                n_depth = rgbd.X_CO[:3, 2]
                chosen = int(np.argmax([h.rotation[:, 2] @ n_depth for h in hyps]))
                resolved_by = "depth"
        if ambiguous and resolved_by == "image" and prior is not None:
            costs = [prior(d.id, h) for h in hyps]
            if None not in costs and abs(costs[0] - costs[1]) > self.config.prior_margin_rad:
                chosen = int(np.argmin(costs))
                resolved_by = "prior"
        X_depth = None
        if depth is not None and self.config.refine_with_depth:
            fused = self._visp.refine_pose_rgbd(
                self._visp.tag_corners(d.tag_size),
                d.corners,
                [(d.corners, np.array([0.0, 0.0, 1.0]), 0.0)],
                depth,
                intrinsics.native,
                hyps[chosen].homogeneous,
                self.config.corner_noise_px,
                self.config.depth_sigma,
                self.config.depth_polygon_scale,
            )
            if fused.ok:
                X_depth = pin.SE3(fused.X_CO)
        return TagDetection(
            X_CT_depth=X_depth,
            tag_id=int(d.id),
            corners=np.asarray(d.corners),
            tag_size=float(d.tag_size),
            hypotheses=hyps,
            reprojection_errors=errors,
            has_second=bool(d.has_second),
            chosen=chosen,
            ambiguous=ambiguous,
            resolved_by=resolved_by,
        )
