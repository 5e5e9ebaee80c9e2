"""``marionette perceive``: camera frames in, tag detections and object poses out, over LCM.

Subscribes ``CAMERA_HEAD`` (``lcmt_camera_image``: RGB8, int16 depth, intrinsics) and
``ROBOT_STATE``; publishes ``APRILTAG_DETECTIONS`` and ``OBJECT_POSES`` for every processed
frame, at camera rate (thesis 000 §3.3.6, Agimus-Vision). Object poses are given in the camera
frame and in the world through the robot's kinematics (the camera pose of the robot state
nearest the image), or through the simulator's camera pose carried by the image.

Frames are processed by one worker thread, newest first: if a frame arrives while the previous
one is still being processed, the older waiting frame is dropped (counted), so latency never
builds up. Malformed frames are rejected with a counted reason, never a crash.

Latency (``latency_us`` of both messages, and :meth:`PerceptionNode.stats`) is measured on this
process's monotonic clock from the frame's arrival to publication: the image ``utime`` is
controller time, which shares no clock with this process, so rendering and transport time
before arrival are not included.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from marionette import channels
from marionette.perception.camera import CameraIntrinsics
from marionette.perception.detector import AprilTagDetector, DetectorConfig, TagDetection
from marionette.perception.kinematics import CameraKinematics, StateError
from marionette.perception.objects import (
    BodyPose,
    TaggedBody,
    estimate_body_poses,
    tilt,
    up_axis_prior,
)
from marionette.perception.tracking import TagRegionTracker, TrackingConfig

if TYPE_CHECKING:
    from marionette.lcm_bus import LcmBus

log = logging.getLogger("marionette.perceive")

MAX_IMAGE_SIDE = 8192


class FrameError(ValueError):
    """A camera frame that cannot be processed; ``reason`` is a short counter key."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass
class Frame:
    """A decoded camera frame."""

    utime: int
    camera_name: str
    intrinsics: CameraIntrinsics
    gray: np.ndarray  # (h, w) uint8
    depth: np.ndarray | None  # (h, w) float32 [m], 0 = no return
    X_WC_message: pin.SE3 | None  # simulator's camera pose, if finite


def camera_image_arrays(data: bytes) -> SimpleNamespace:
    """An ``lcmt_camera_image`` decoded by lcm-gen's C++ decoder, its rgb and depth as numpy
    arrays (lcm-gen's Python decoder makes the depth a tuple of Python ints, then numpy an array
    of them: a quarter of this process's time in a deburr trial); the same fields otherwise."""
    from marionette._wire import decode_camera_image

    return SimpleNamespace(**decode_camera_image(data))


def decode_frame(msg) -> Frame:
    """Checks an ``lcmt_camera_image`` and converts it; raises :class:`FrameError`."""
    w, h = int(msg.width), int(msg.height)
    if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE):
        raise FrameError("bad_size", f"image size {w} x {h}")
    try:
        intrinsics = CameraIntrinsics(
            w, h, float(msg.fx), float(msg.fy), float(msg.cx), float(msg.cy)
        )
    except ValueError as exc:
        raise FrameError("bad_intrinsics", str(exc)) from None
    if msg.num_rgb != w * h * 3 or len(msg.rgb) != w * h * 3:
        raise FrameError("rgb_size", f"{len(msg.rgb)} RGB bytes for {w} x {h} x 3")
    rgb = np.frombuffer(bytes(msg.rgb), dtype=np.uint8).reshape(h, w, 3)
    # ITU-R BT.601 luma in integer arithmetic: (77 R + 150 G + 29 B) / 256.
    gray = (
        (
            rgb[:, :, 0].astype(np.uint16) * 77
            + rgb[:, :, 1].astype(np.uint16) * 150
            + rgb[:, :, 2].astype(np.uint16) * 29
        )
        >> 8
    ).astype(np.uint8)
    depth = None
    if msg.num_depth != 0:
        if msg.num_depth != w * h or len(msg.depth) != w * h:
            raise FrameError("depth_size", f"{len(msg.depth)} depth values for {w} x {h}")
        scale = float(msg.depth_scale)
        if not (math.isfinite(scale) and scale > 0.0):
            raise FrameError("depth_scale", f"depth_scale must be finite and > 0, got {scale}")
        raw = np.asarray(msg.depth, dtype=np.int16).reshape(h, w)
        depth = np.where(raw > 0, raw.astype(np.float32) * np.float32(scale), np.float32(0.0))
    X_WC = None
    p = np.asarray(msg.camera_position, dtype=float)
    qw, qx, qy, qz = (float(a) for a in msg.camera_quaternion)
    norm = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if np.all(np.isfinite(p)) and math.isfinite(norm) and abs(norm - 1.0) < 1e-3:
        X_WC = pin.SE3(pin.Quaternion(qw / norm, qx / norm, qy / norm, qz / norm).matrix(), p)
    return Frame(int(msg.utime), str(msg.camera_name), intrinsics, gray, depth, X_WC)


def _wxyz(R: np.ndarray) -> list[float]:
    q = pin.Quaternion(R)
    q.normalize()
    return [q.w, q.x, q.y, q.z]


def detections_message(frame: Frame, detections: Sequence[TagDetection], latency_us: float):
    """``lcmt_apriltag_detections``; the retained hypothesis's slot holds ``X_CT`` (refined
    with depth when there was depth), the other slot the image-only alternative."""
    from marionette import lcmt_apriltag_detection, lcmt_apriltag_detections

    out = lcmt_apriltag_detections()
    out.utime = frame.utime
    out.camera_name = frame.camera_name
    out.latency_us = float(latency_us)
    for d in detections:
        m = lcmt_apriltag_detection()
        m.utime = frame.utime
        m.family = "tag36h11"
        m.id = d.tag_id
        m.tag_size = d.tag_size
        m.corners = [list(map(float, c)) for c in d.corners]
        poses = list(d.hypotheses)
        poses[d.chosen] = d.X_CT
        m.position = [list(map(float, X.translation)) for X in poses]
        m.quaternion = [_wxyz(X.rotation) for X in poses]
        m.reprojection_error = list(map(float, d.reprojection_errors))
        m.chosen = d.chosen
        m.ambiguous = d.ambiguous
        m.resolved_by = d.resolved_by
        out.detections.append(m)
    out.num_detections = len(out.detections)
    return out


def object_poses_message(
    frame: Frame, poses: Sequence[BodyPose], X_WC: pin.SE3 | None, latency_us: float
):
    """``lcmt_object_poses``; world fields are NaN when the camera's world pose is unknown."""
    from marionette import lcmt_object_pose, lcmt_object_poses

    out = lcmt_object_poses()
    out.utime = frame.utime
    out.camera_name = frame.camera_name
    out.latency_us = float(latency_us)
    for pose in poses:
        m = lcmt_object_pose()
        m.utime = frame.utime
        m.object_name = pose.name
        m.position_camera = list(map(float, pose.X_CB.translation))
        m.quaternion_camera = _wxyz(pose.X_CB.rotation)
        if X_WC is not None:
            X_WB = X_WC * pose.X_CB
            m.position_world = list(map(float, X_WB.translation))
            m.quaternion_world = _wxyz(X_WB.rotation)
        else:
            m.position_world = [math.nan] * 3
            m.quaternion_world = [math.nan] * 4
        m.tag_id = list(pose.tag_ids)
        m.num_tags = len(m.tag_id)
        m.reprojection_error = float(pose.reprojection_rms)
        m.ambiguous = pose.ambiguous
        out.objects.append(m)
    out.num_objects = len(out.objects)
    return out


@dataclass
class PerceptionConfig:
    """What ``perceive`` looks for and how it places the camera."""

    bodies: list[TaggedBody]
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    camera_channel: str = channels.CAMERA_HEAD
    use_depth: bool = True
    camera_pose_source: str = "kinematics"  # "kinematics" (ROBOT_STATE) or "message"
    # body name -> axis of the body expected to point up (graph state: resting on a table)
    up_axes: dict[str, np.ndarray] = field(default_factory=dict)
    # Search each frame around the tags of the previous one (whole image now and then).
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    # [m] publish a body's pose only when its origin is known to within this (1 σ from the tag
    # corners, objects.position_sigma): one tag at the end of a long bar, seen close and
    # oblique, placed the bar's centre 24 mm off; inf = every pose.
    max_position_sigma: float = math.inf
    # [deg] publish a body that rests with an axis up (``up_axes``) only when its estimate tilts
    # that axis by at most this: a single tag seen obliquely from a turning head was estimated
    # 10-18 deg off (2 of 500 estimates; the others within 1 deg), and a pedestal's top, 0.88 m
    # from its origin, moved 15 cm with it; inf = every pose.
    max_tilt_deg: float = math.inf


class LatencyWindow:
    """Percentiles of the last ``size`` latencies [us] (thread-safe)."""

    def __init__(self, size: int = 300) -> None:
        self._values: deque[float] = deque(maxlen=size)
        self._lock = threading.Lock()

    def add(self, value_us: float) -> None:
        with self._lock:
            self._values.append(value_us)

    def summary(self) -> dict[str, float]:
        with self._lock:
            v = np.array(self._values)
        if v.size == 0:
            return {"n": 0}
        return {
            "n": int(v.size),
            "p50_us": float(np.percentile(v, 50)),
            "p99_us": float(np.percentile(v, 99)),
            "max_us": float(v.max()),
        }


class PerceptionNode:
    """The perceive process's logic, transport-agnostic: :meth:`process` maps a frame to the
    two messages; :meth:`attach` wires it to an :class:`~marionette.lcm_bus.LcmBus`."""

    def __init__(
        self, config: PerceptionConfig, kinematics: CameraKinematics | None = None
    ) -> None:
        if config.camera_pose_source not in ("kinematics", "message"):
            raise ValueError(
                f"camera_pose_source must be kinematics or message, "
                f"got {config.camera_pose_source!r}"
            )
        if config.camera_pose_source == "kinematics" and kinematics is None:
            raise ValueError("camera_pose_source 'kinematics' needs a robot model (--robot)")
        self.config = config
        self.kinematics = kinematics
        sizes = dict(config.detector.tag_sizes)
        for body in config.bodies:
            sizes.update(body.tag_sizes())
        config.detector.tag_sizes = sizes
        self.detector = AprilTagDetector(config.detector)
        self.tracker = TagRegionTracker(config.tracking)
        self.counters: Counter = Counter()
        self.rejected: Counter = Counter()
        self.latency = LatencyWindow()
        self._pending: tuple[object, float] | None = None  # (message, receive time)
        self._cond = threading.Condition()
        self._bus: LcmBus | None = None

    # ---- processing ------------------------------------------------------------------------
    def camera_pose(self, frame: Frame) -> pin.SE3 | None:
        # The constructor refuses camera_pose_source "kinematics" without kinematics.
        if self.config.camera_pose_source == "message" or self.kinematics is None:
            return frame.X_WC_message
        found = self.kinematics.camera_pose(frame.utime)
        return None if found is None else found[0]

    def process(self, msg, received: float):
        """(detections message, object poses message) for one ``lcmt_camera_image``.

        Raises :class:`FrameError` for a malformed frame.
        """
        frame = decode_frame(msg)
        depth = frame.depth if self.config.use_depth else None
        X_WC = self.camera_pose(frame)
        prior = None
        if self.config.up_axes and X_WC is not None:
            prior = up_axis_prior(self.config.bodies, self.config.up_axes, X_WC.rotation)
        regions = self.tracker.regions()
        detections = self.detector.detect(
            frame.gray, frame.intrinsics, depth=depth, prior=prior, regions=regions
        )
        self.tracker.update(detections, regions)
        poses = estimate_body_poses(
            self.config.bodies,
            detections,
            frame.intrinsics,
            depth=depth,
            ambiguity_ratio=self.config.detector.ambiguity_ratio,
            corner_noise_px=self.config.detector.corner_noise_px,
            depth_sigma=self.config.detector.depth_sigma,
            depth_polygon_scale=self.config.detector.depth_polygon_scale,
        )
        if X_WC is None:
            self.counters["no_camera_pose"] += 1
        imprecise = [
            n for n, p in poses.items() if p.position_sigma > self.config.max_position_sigma
        ]
        for name in imprecise:
            del poses[name]
        self.counters["imprecise_poses"] += len(imprecise)
        if X_WC is not None and math.isfinite(self.config.max_tilt_deg):
            tilted = [
                n
                for n, p in poses.items()
                if n in self.config.up_axes
                and math.degrees(tilt(X_WC.rotation @ p.X_CB.rotation, self.config.up_axes[n]))
                > self.config.max_tilt_deg
            ]
            for name in tilted:
                del poses[name]
            self.counters["tilted_poses"] += len(tilted)
        latency_us = (time.monotonic() - received) * 1e6
        return (
            detections_message(frame, detections, latency_us),
            object_poses_message(frame, list(poses.values()), X_WC, latency_us),
        )

    # ---- transport -------------------------------------------------------------------------
    def attach(self, bus: LcmBus) -> None:
        """Subscribes the camera channel and, for kinematics, ROBOT_STATE on ``bus``."""
        from marionette import lcmt_camera_image, lcmt_robot_state

        self._bus = bus
        bus.subscribe(
            self.config.camera_channel, lcmt_camera_image, self._on_image, camera_image_arrays
        )
        if self.kinematics is not None:
            bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)

    def _on_image(self, msg) -> None:
        with self._cond:
            self.counters["frames_received"] += 1
            if self._pending is not None:
                self.counters["frames_dropped"] += 1
            self._pending = (msg, time.monotonic())
            self._cond.notify()

    def _on_state(self, msg) -> None:
        if self.kinematics is None:  # attach() subscribes ROBOT_STATE only with kinematics
            return
        try:
            self.kinematics.add_state(msg)
        except StateError as exc:
            self.rejected["robot_state"] += 1
            if self.rejected["robot_state"] == 1:
                log.warning("robot state rejected: %s", exc)

    def step(self, timeout_s: float) -> bool:
        """Processes the newest waiting frame (waits up to ``timeout_s``); True if one was."""
        if self._bus is None:
            raise RuntimeError("attach() the perception node to a bus before step()")
        with self._cond:
            if self._pending is None:
                self._cond.wait(timeout_s)
            if self._pending is None:
                return False
            msg, received = self._pending
            self._pending = None
        try:
            detections, objects = self.process(msg, received)
        except FrameError as exc:
            self.rejected[exc.reason] += 1
            if self.rejected[exc.reason] == 1:
                log.warning("frame rejected: %s", exc)
            return True
        except Exception:  # a bug must not stop the camera stream: count it, log it once
            self.rejected["processing_error"] += 1
            if self.rejected["processing_error"] == 1:
                log.exception("frame processing failed")
            return True
        self._bus.publish(channels.APRILTAG_DETECTIONS, detections)
        self._bus.publish(channels.OBJECT_POSES, objects)
        self.latency.add((time.monotonic() - received) * 1e6)
        self.counters["frames_processed"] += 1
        return True

    def stats(self) -> dict:
        """Counters, rejections by reason and processing latency (receive -> publish)."""
        return {
            **self.counters,
            "rejected": dict(self.rejected),
            "latency": self.latency.summary(),
            "tracking": dict(self.tracker.counts),
            "noise_sigma": round(float(self.detector.last_stats.noise_sigma), 2),
        }
