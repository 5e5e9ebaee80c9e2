"""Poses of tagged bodies (objects, robot links) from all their visible tags at once.

A body carries several tags (thesis 000 §5.2.1, fig. 5.2: the robot's own arms often hide one);
its pose is estimated from the corners of *every* visible tag in one Gauss-Newton (ViSP virtual
visual servoing), so any non-empty subset of its tags yields the pose, and more tags make it
more precise and less ambiguous. Tags are declared in the models' YAML
(:mod:`marionette.models.semantics`: id, size, link, pose in the link frame).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import TagDetection, errors_ambiguous, rotation_angle


@dataclass(frozen=True)
class TagOnBody:
    """A tag of a body: black-square edge ``size`` [m] and pose ``X_BT`` in the body frame."""

    tag_id: int
    size: float
    X_BT: pin.SE3


@dataclass(frozen=True)
class TaggedBody:
    """A rigid body seen through its tags: an object's ``base_link`` or a robot link."""

    name: str  # object name, or "<robot>/<link>"
    link: str
    tags: tuple[TagOnBody, ...]

    def __post_init__(self) -> None:
        ids = [t.tag_id for t in self.tags]
        if not ids:
            raise ValueError(f"{self.name}: a tagged body needs at least one tag")
        if len(set(ids)) != len(ids):
            raise ValueError(f"{self.name}: duplicate tag ids {ids}")

    def tag(self, tag_id: int) -> TagOnBody | None:
        return next((t for t in self.tags if t.tag_id == tag_id), None)

    def require_tag(self, tag_id: int) -> TagOnBody:
        """Tag ``tag_id`` of this body; raises KeyError naming the body when it has none."""
        t = self.tag(tag_id)
        if t is None:
            raise KeyError(f"{self.name} has no tag {tag_id}")
        return t

    def tag_sizes(self) -> dict[int, float]:
        return {t.tag_id: t.size for t in self.tags}

    def corners_B(self, tag_id: int) -> np.ndarray:
        """(4, 3) corners of the tag's black square in the body frame, detection order."""
        from marionette import _visp

        t = self.require_tag(tag_id)
        return (t.X_BT.homogeneous @ np.c_[_visp.tag_corners(t.size), np.ones(4)].T).T[:, :3]


@dataclass(frozen=True)
class BodyPose:
    """Pose of a tagged body in the camera frame, from the tags listed in ``tag_ids``."""

    name: str
    X_CB: pin.SE3
    tag_ids: tuple[int, ...]
    reprojection_rms: float  # [px] over all corners used
    ambiguous: bool  # another pose explained the corners about as well
    resolved_by: str  # "image" | "depth" | "prior"
    # [m] 1 σ of the body origin's position from the tag corners alone (position_sigma)
    position_sigma: float = math.inf


_UP_W = np.array([0.0, 0.0, 1.0])  # world z, the default "up" of a resting body
_UP_W.flags.writeable = False


def tagged_bodies_from_semantics(semantics) -> list[TaggedBody]:
    """One :class:`TaggedBody` per link carrying tags in a :class:`Semantics` declaration."""
    by_link: dict[str, list[TagOnBody]] = {}
    for t in semantics.tags:
        if t.family != "tag36h11":
            raise ValueError(
                f"{semantics.name}: tag {t.id} is {t.family}; only tag36h11 is detected"
            )
        by_link.setdefault(t.link, []).append(TagOnBody(t.id, t.size, t.pose.se3()))
    single = len(by_link) == 1
    return [
        TaggedBody(semantics.name if single else f"{semantics.name}/{link}", link, tuple(tags))
        for link, tags in by_link.items()
    ]


def load_tagged_bodies(paths: Iterable[str | Path]) -> list[TaggedBody]:
    """Tagged bodies of every ``models/**/<name>.yaml`` given; tag ids must be unique overall."""
    from marionette.models.semantics import load_semantics

    bodies: list[TaggedBody] = []
    for path in paths:
        bodies.extend(tagged_bodies_from_semantics(load_semantics(path)))
    check_unique_ids(bodies)
    return bodies


def check_unique_ids(bodies: Sequence[TaggedBody]) -> None:
    seen: dict[int, str] = {}
    for body in bodies:
        for t in body.tags:
            if t.tag_id in seen:
                raise ValueError(
                    f"tag {t.tag_id} is declared on both {seen[t.tag_id]} and {body.name}"
                )
            seen[t.tag_id] = body.name


def tag_sizes(bodies: Sequence[TaggedBody]) -> dict[int, float]:
    """Tag id -> size over all bodies (for :class:`DetectorConfig`)."""
    sizes: dict[int, float] = {}
    for body in bodies:
        sizes.update(body.tag_sizes())
    return sizes


def estimate_body_pose(
    body: TaggedBody,
    detections: Sequence[TagDetection],
    intrinsics: CameraIntrinsics,
    depth: np.ndarray | None = None,
    ambiguity_ratio: float = 0.2,
    corner_noise_px: float = 0.3,
    depth_sigma: float = 0.003,
    depth_polygon_scale: float = 1.1,
) -> BodyPose | None:
    """Pose of ``body`` from the corners of all its detected tags, or None if none is visible.

    Every hypothesis of every visible tag seeds a refinement over all corners; distinct local
    minima are ranked by reprojection error. When the runner-up is about as good (the tag test,
    :func:`errors_ambiguous`), the minimum reached from the tags' *retained* hypotheses wins
    (those carry the depth or prior decision) and ``ambiguous`` is set. With ``depth`` (h, w)
    [m], the result is refined on corners and the depth pixels of every visible tag's plane,
    the depth weighted with the noise its residuals show (``depth_sigma``: the first guess).
    """
    from marionette import _visp

    best_per_tag: dict[int, TagDetection] = {}
    for d in detections:  # a tag seen twice (a false positive): keep the better fit
        if body.tag(d.tag_id) is not None:
            kept = best_per_tag.get(d.tag_id)
            if (
                kept is None
                or d.reprojection_errors[d.chosen] < kept.reprojection_errors[kept.chosen]
            ):
                best_per_tag[d.tag_id] = d
    mine = [best_per_tag[i] for i in sorted(best_per_tag)]
    if not mine:
        return None
    p_B = np.vstack([body.corners_B(d.tag_id) for d in mine])
    uv = np.vstack([d.corners for d in mine])
    # (error, X_CB, reached from a retained hypothesis)
    minima: list[tuple[float, pin.SE3, bool]] = []
    for d in mine:
        X_TB = body.require_tag(d.tag_id).X_BT.inverse()
        for k, X_CT in enumerate(d.hypotheses[: 2 if d.has_second else 1]):
            est = _visp.refine_pose(p_B, uv, intrinsics.native, (X_CT * X_TB).homogeneous)
            if not est.ok:
                continue
            X = pin.SE3(est.X_CO)
            retained = k == d.chosen
            same = next(
                (
                    i
                    for i, m in enumerate(minima)
                    if rotation_angle(m[1].rotation, X.rotation) < 1e-2
                ),
                None,
            )
            if same is None:
                minima.append((est.reprojection_error, X, retained))
            elif retained:
                minima[same] = (minima[same][0], minima[same][1], True)
    if not minima:
        return None
    minima.sort(key=lambda m: m[0])
    best = minima[0]
    ambiguous = len(minima) > 1 and errors_ambiguous(
        minima[0][0], minima[1][0], len(uv), ambiguity_ratio, corner_noise_px
    )
    resolved_by = "image"
    if ambiguous:
        decided = [d.resolved_by for d in mine if d.resolved_by != "image"]
        if decided:
            best = next((m for m in minima if m[2]), best)
            resolved_by = decided[0]
    X_CB, error = best[1], best[0]
    if depth is not None:
        planes = []
        for d in mine:
            X_BT = body.require_tag(d.tag_id).X_BT
            n_B = X_BT.rotation[:, 2]
            planes.append((d.corners, n_B, float(n_B @ X_BT.translation)))
        fused = _visp.refine_pose_rgbd(
            p_B,
            uv,
            planes,
            depth,
            intrinsics.native,
            X_CB.homogeneous,
            corner_noise_px,
            depth_sigma,
            depth_polygon_scale,
        )
        if fused.ok:
            X_CB, error = pin.SE3(fused.X_CO), fused.reprojection_error
    rms = math.sqrt(error / len(uv))
    sigma = position_sigma(p_B, X_CB, intrinsics, corner_noise_px)
    return BodyPose(
        body.name, X_CB, tuple(d.tag_id for d in mine), rms, ambiguous, resolved_by, sigma
    )


def position_sigma(
    p_B: np.ndarray, X_CB: pin.SE3, intrinsics: CameraIntrinsics, corner_noise_px: float
) -> float:
    """Largest standard deviation [m] of the body origin's position estimated from the corners
    ``p_B`` (n, 3) seen at ``X_CB`` with independent pixel noise ``corner_noise_px``: the
    Gauss–Newton covariance σ² (JᵀJ)⁻¹ of the pose, J the corners' image Jacobian with respect
    to a motion of the body frame. A tag's pose turns more than it slides, and the turn moves a
    body origin far from the tag: TALOS' head camera placed the step-over bar's centre, 0.65 m
    from either end's 8 cm tags, within 11-25 mm from one end and 0.9-3.1 mm from both. Depth
    is left out (it only sharpens the estimate). inf when the corners do not fix the pose."""
    p_B = np.asarray(p_B, dtype=float)
    R = X_CB.rotation
    p_C = p_B @ R.T + X_CB.translation
    x, y, z = p_C[:, 0], p_C[:, 1], p_C[:, 2]
    # d(u, v)/dp_C per corner, and dp_C = R (dt + dθ × p_B) for a motion (dt, dθ) of the body frame
    du = np.stack([intrinsics.fx / z, np.zeros_like(z), -intrinsics.fx * x / z**2], axis=1)
    dv = np.stack([np.zeros_like(z), intrinsics.fy / z, -intrinsics.fy * y / z**2], axis=1)
    d_uv = np.stack([du, dv], axis=1) @ R  # (n, 2, 3): with respect to dt in the body frame
    skew = np.zeros((len(p_B), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -p_B[:, 2], p_B[:, 1], -p_B[:, 0]
    skew -= skew.transpose(0, 2, 1)  # [p_B]×
    J = np.concatenate([d_uv, -d_uv @ skew], axis=2).reshape(-1, 6)
    JtJ = J.T @ J
    if np.linalg.cond(JtJ) > 1e12:
        return math.inf
    covariance = corner_noise_px**2 * np.linalg.inv(JtJ)
    return float(math.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3]).max(), 0.0)))


def estimate_body_poses(
    bodies: Sequence[TaggedBody],
    detections: Sequence[TagDetection],
    intrinsics: CameraIntrinsics,
    **kwargs,
) -> dict[str, BodyPose]:
    """:func:`estimate_body_pose` for every body with at least one visible tag."""
    out = {}
    for body in bodies:
        pose = estimate_body_pose(body, detections, intrinsics, **kwargs)
        if pose is not None:
            out[body.name] = pose
    return out


def tilt(R_WB: np.ndarray, up_B: np.ndarray, up_W: np.ndarray = _UP_W) -> float:
    """The angle [rad] between a body's axis ``up_B`` (its frame), turned by ``R_WB``, and
    ``up_W`` (default the world's z)."""
    u = R_WB @ (np.asarray(up_B, dtype=float) / np.linalg.norm(up_B))
    return float(
        math.acos(np.clip(u @ (np.asarray(up_W, dtype=float) / np.linalg.norm(up_W)), -1.0, 1.0))
    )


def up_axis_prior(
    bodies: Sequence[TaggedBody],
    up_B: Mapping[str, np.ndarray],
    R_WC: np.ndarray,
    up_W: np.ndarray = _UP_W,
):
    """A hypothesis prior from the graph state "body B rests with axis ``up_B[name]`` up".

    For a tag hypothesis X_CT the implied body up axis in the world is
    R_WC R_CT R_TB up_B; its angle to ``up_W`` is the cost (thesis 000 §5.2.1: the state of the
    constraint graph, e.g. the plank lying on the table, tells which tilt is plausible).
    """
    table: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for body in bodies:
        if body.name in up_B:
            u = np.asarray(up_B[body.name], dtype=float)
            u = u / np.linalg.norm(u)
            for t in body.tags:
                table[t.tag_id] = (t.X_BT.rotation.T, u)
    up_W = np.asarray(up_W, dtype=float) / np.linalg.norm(up_W)

    def prior(tag_id: int, X_CT: pin.SE3) -> float | None:
        entry = table.get(tag_id)
        if entry is None:
            return None
        R_TB, u = entry
        return tilt(R_WC @ X_CT.rotation @ R_TB, u, up_W)

    return prior
