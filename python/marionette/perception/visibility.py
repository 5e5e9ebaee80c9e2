"""What the camera can see of a tagged body, predicted from the kinematics before any image: the
tags that face the lens, lie inside the image and are not hidden by the robot's own links.

Two users: the encoder calibration plans arm configurations that show the wrist ring
(:mod:`.arm_calibration`), and the visual servo's gaze leans the torso when the head alone
cannot bring the servoed object's tags into view (:mod:`marionette.execution.visual_servo`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from marionette.perception.camera import CameraIntrinsics
from marionette.perception.objects import TaggedBody


@dataclass
class LineOfSight:
    """Self-occlusion by the robot's own collision model: a segment from the camera to a point (a
    3 mm capsule stopping 1 cm short of it) hitting a link other than ``tagged_link`` (whose hull
    holds a ring of tags on the robot; None for an object) and those that carry the camera (whose
    hull holds the lens) hides the point — the forearm, seen from the head, covers the wrist ring
    in a third of the views the tags face; the hand holding an object covers its tags."""

    model: pin.Model
    geom: pin.GeometryModel
    tagged_link: str | None
    camera_frame: str
    radius: float = 0.003

    def __post_init__(self) -> None:
        import hppfcl

        self._fcl = hppfcl
        self.gdata = pin.GeometryData(self.geom)
        camera_joint = self.model.frames[self.model.getFrameId(self.camera_frame)].parentJoint
        self.others = [
            i
            for i, o in enumerate(self.geom.geometryObjects)
            if not (self.tagged_link is not None and o.name.startswith(self.tagged_link))
            and o.parentJoint != camera_joint
        ]
        self.request = hppfcl.CollisionRequest()

    def update(self, data: pin.Data) -> None:
        """The geometries placed at the kinematics already computed in ``data``."""
        pin.updateGeometryPlacements(self.model, data, self.geom, self.gdata)

    def clear(self, p_W_camera: np.ndarray, p_W_target: np.ndarray) -> bool:
        """True when nothing of the robot but the tagged link and the camera's lies between the
        two points (placements from the last :meth:`update`)."""
        fcl = self._fcl
        d = p_W_target - p_W_camera
        length = float(np.linalg.norm(d)) - 0.01
        if length <= 0.0:
            return True
        z = d / np.linalg.norm(d)
        R = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), z).matrix()
        capsule = fcl.Capsule(self.radius, length)
        X = fcl.Transform3s(R, p_W_camera + z * length / 2)
        for i in self.others:
            placement = self.gdata.oMg[i]
            X_o = fcl.Transform3s(placement.rotation, placement.translation)
            geometry = self.geom.geometryObjects[i].geometry
            if fcl.collide(capsule, X, geometry, X_o, self.request, fcl.CollisionResult()):
                return False
        return True


@dataclass(frozen=True)
class ViewLimits:
    """What a detectable tag needs: its centre ``margin_px`` inside the image (and, with
    ``corner_margin_px``, its four corners that far inside: a tag cut by the image's edge is not
    detected), ``min_depth`` to ``max_depth`` in front of the lens, its normal within
    ``max_angle_deg`` of the line of sight."""

    margin_px: float = 60.0
    corner_margin_px: float | None = None
    min_depth: float = 0.3  # [m]
    max_depth: float = 0.75  # [m]
    max_angle_deg: float = 55.0


def tags_in_view(
    X_WC: pin.SE3,
    X_WB: pin.SE3,
    body: TaggedBody,
    intrinsics: CameraIntrinsics,
    limits: ViewLimits = ViewLimits(),
    sight: LineOfSight | None = None,
) -> int:
    """How many of ``body``'s tags (body at ``X_WB``) the camera at ``X_WC`` (optical frame)
    would detect: facing it and inside the image within ``limits`` and, with ``sight`` (updated
    at the same kinematics), not hidden by the robot (centre and corners)."""
    X_CB = X_WC.actInv(X_WB)
    cos_max = np.cos(np.radians(limits.max_angle_deg))
    seen = 0
    for tag in body.tags:
        X_CT = X_CB * tag.X_BT
        p = X_CT.translation
        if not limits.min_depth < p[2] < limits.max_depth:
            continue
        u, v = intrinsics.project(p)[0]
        m = limits.margin_px
        if not (m < u < intrinsics.width - m and m < v < intrinsics.height - m):
            continue
        if -X_CT.rotation[:, 2] @ (p / np.linalg.norm(p)) <= cos_max:
            continue
        # the centre and the four corners in sight (a tag half hidden is not detected)
        h = tag.size / 2
        points = [np.zeros(3), *(np.array([a * h, b * h, 0.0]) for a in (-1, 1) for b in (-1, 1))]
        if limits.corner_margin_px is not None:
            c = limits.corner_margin_px
            uv = intrinsics.project(np.array([X_CT.act(x) for x in points[1:]]))
            if not (
                np.all((c < uv[:, 0]) & (uv[:, 0] < intrinsics.width - c))
                and np.all((c < uv[:, 1]) & (uv[:, 1] < intrinsics.height - c))
            ):
                continue
        if sight is None or all(
            sight.clear(X_WC.translation, X_WC.act(X_CT.act(c))) for c in points
        ):
            seen += 1
    return seen
