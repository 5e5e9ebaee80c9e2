"""The sensors a robot carries on its tool - its camera and its laser range-finders - read over
LCM and expressed in the tool frame (thesis 000 §6.2-6.3: the drilling end effector's cameras and
lasers).

The camera's frames come on CAMERA_HEAD (the robot's first camera, rendered by the simulator or
sent by a driver), the lasers' distances on RANGE_FINDERS. Where the camera and the lasers sit on
the tool is robot data (``cameras``, ``range_finders`` of the robot's description): their poses in
the tool frame follow from the robot's kinematics, which are rigid between them. The pose of the
camera that a simulator writes in its messages is never used: a real camera does not know it.

:class:`ToolSensors` waits for readings taken after a given controller time (the arm still), and
measures with :mod:`marionette.perception.hole_sensor`.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pinocchio as pin

from marionette import channels, lcmt_camera_image, lcmt_range_finders, robots
from marionette.control.client import ControllerClient
from marionette.execution.tool_task import ToolTask
from marionette.perception.hole_sensor import (
    HoleMeasurement,
    HoleNotSeen,
    Plane,
    find_hole,
    skin_plane,
)
from marionette.perception.node import Frame, FrameError, decode_frame


class ToolSensors:
    """The tool's camera and range finders of ``tool``'s robot, read on ``client``'s bus.

    ``samples``: range readings averaged per plane (each a distinct controller time)."""

    def __init__(self, client: ControllerClient, tool: ToolTask, samples: int = 4) -> None:
        desc = robots.robot(tool.robot)
        if not desc.cameras:
            raise ValueError(f"{tool.robot} has no camera (cameras: in its robot.yaml)")
        if len(desc.range_finders) < 3:
            raise ValueError(
                f"{tool.robot} has {len(desc.range_finders)} range finders (range_finders: in its "
                "robot.yaml); a plane needs three"
            )
        self.samples = max(1, samples)
        for frame in [desc.cameras[0].frame] + [r.frame for r in desc.range_finders]:
            if not tool.model.existFrame(frame):
                raise ValueError(f"{tool.robot}: no frame {frame} in its model")
        self._beam_names = [r.name for r in desc.range_finders]
        # Where the camera and the beams sit in the tool frame F: rigid on the tool, so the
        # kinematics at any configuration give them.
        X_WF = tool.tool_of(pin.neutral(tool.model))  # runs the frames' forward kinematics
        oMf = tool.data.oMf
        self.X_FC = X_WF.actInv(oMf[tool.model.getFrameId(desc.cameras[0].frame)])
        beams = [X_WF.actInv(oMf[tool.model.getFrameId(r.frame)]) for r in desc.range_finders]
        self._beam_origins = np.array([b.translation for b in beams])
        self._beam_directions = np.array([b.rotation[:, 2] for b in beams])
        self._lock = threading.Condition()
        self._frame: Frame | None = None
        self._ranges: list[tuple[int, dict[str, float]]] = []
        self.frames_used = 0
        self.range_readings = 0
        self.refused_frames = 0
        self.last_refusal = ""
        # the last hole measured: (grey image, intrinsics, X_FC, measurement), for reports
        self.last_view: tuple[np.ndarray, object, pin.SE3, HoleMeasurement] | None = None
        client.bus.subscribe(channels.CAMERA_HEAD, lcmt_camera_image, self._on_frame)
        client.bus.subscribe(channels.RANGE_FINDERS, lcmt_range_finders, self._on_ranges)

    # ---- LCM ----------------------------------------------------------------------------------

    def _on_frame(self, msg) -> None:
        try:
            frame = decode_frame(msg)
        except FrameError as e:
            with self._lock:
                self.refused_frames += 1
                self.last_refusal = str(e)
            return
        with self._lock:
            self._frame = frame
            self._lock.notify_all()

    def _on_ranges(self, msg) -> None:
        reading = dict(zip(msg.name, (float(d) for d in msg.distance)))
        with self._lock:
            self._ranges.append((int(msg.utime), reading))
            del self._ranges[: max(0, len(self._ranges) - 64)]
            self._lock.notify_all()

    def _wait(self, ready, what: str, timeout_s: float = 10.0):
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while (value := ready()) is None:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    raise HoleNotSeen(f"no {what} in {timeout_s:.0f} s")
                self._lock.wait(left)
            return value

    # ---- measurements -------------------------------------------------------------------------

    def plane(self, since_utime: int) -> Plane:
        """The skin's plane in the tool frame, from ``samples`` range readings taken at or after
        controller time ``since_utime`` (each beam's distances averaged)."""
        names = self._beam_names

        def ready():
            fresh = [r for t, r in self._ranges if t >= since_utime]
            return fresh[: self.samples] if len(fresh) >= self.samples else None

        readings = self._wait(ready, "RANGE_FINDERS readings")
        missing = [n for n in names if any(n not in r for r in readings)]
        if missing:
            raise HoleNotSeen(f"RANGE_FINDERS has no reading of {', '.join(missing)}")
        distances = np.array([[r[n] for n in names] for r in readings])
        self.range_readings += len(readings)
        # a beam that missed once missed: keep its negative reading rather than average it away
        d = np.where((distances < 0).any(axis=0), -1.0, distances.mean(axis=0))
        return skin_plane(self._beam_origins, self._beam_directions, d)

    def hole(
        self,
        X_W_tool: pin.SE3,
        expected_W: np.ndarray,
        hole_radius: float,
        search_radius: float,
        since_utime: int,
    ) -> HoleMeasurement:
        """The hole expected at ``expected_W`` (world, e.g. from a camera estimate), measured in
        the tool frame of ``X_W_tool`` (the tool pose the readings were taken at) from a camera
        frame and range readings taken at or after ``since_utime``."""
        plane = self.plane(since_utime)
        frame = self._wait(
            lambda: (
                self._frame
                if self._frame is not None and self._frame.utime >= since_utime
                else None
            ),
            "tool camera frame (CAMERA_HEAD)",
        )
        self.frames_used += 1
        m = find_hole(
            frame.gray,
            frame.intrinsics,
            self.X_FC,
            plane,
            X_W_tool.actInv(np.asarray(expected_W, dtype=float)),
            hole_radius,
            search_radius,
        )
        self.last_view = (frame.gray, frame.intrinsics, self.X_FC, m)
        return m
