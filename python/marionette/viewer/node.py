"""The viewer process: ``marionette view --robot R [--scene S]`` serves a browser 3D view of a run.

It starts a meshcat server (a child in its own process group, so the demo's ProcessGroup stops
both), subscribes to ROBOT_STATE, SIM_OBJECT_POSES, OBJECT_POSES, FOOTSTEP_PLAN and
SUPERVISOR_STATE on the run's LCM URL, and draws them with :class:`.scene.ViewerScene`. The
robot is redrawn at most ``rate_hz`` times a second (ROBOT_STATE comes at up to 1 kHz; each
redraw is one meshcat command per mesh). The page's URL is printed and, with ``--url-file``,
written to a file once the scene is ready (the demo and the tests read it).
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from marionette import (
    channels,
    lcmt_footstep_plan,
    lcmt_object_poses,
    lcmt_robot_state,
    lcmt_supervisor_state,
)
from marionette.lcm_bus import LcmBus


class MeshcatServer:
    """meshcat's zmq/web server as a child process of ours (meshcat's own launcher puts it in a
    new session, where the SIGINT that stops our process group would not reach it)."""

    def __init__(self, timeout_s: float = 30.0) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-u", "-m", "meshcat.servers.zmqserver"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        assert self.proc.stdout is not None  # stdout=PIPE: Popen made the pipe
        self.output = self.proc.stdout
        self.zmq_url = self.web_url = ""
        deadline = time.monotonic() + timeout_s
        while not self.zmq_url and time.monotonic() < deadline:
            line = self.output.readline()
            if not line and self.proc.poll() is not None:
                raise RuntimeError(f"meshcat server exited with code {self.proc.returncode}")
            m = re.search(r"zmq_url=(\S+)", line)
            if m:
                self.zmq_url = m.group(1)
            m = re.search(r"web_url=(\S+)", line)
            if m:
                self.web_url = m.group(1)
        if not self.zmq_url:
            self.close()
            raise RuntimeError(f"meshcat server gave no zmq_url within {timeout_s} s")
        if not self.web_url:  # printed on the same or the next line
            m = re.search(r"web_url=(\S+)", self.output.readline())
            self.web_url = m.group(1) if m else ""
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self) -> None:
        for _ in self.output:  # keep the pipe from filling up
            pass

    def visualizer(self):
        import meshcat

        return meshcat.Visualizer(zmq_url=self.zmq_url)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


class ViewerNode:
    """Feeds the run's messages to a :class:`ViewerScene` from the LCM thread, one at a time."""

    def __init__(self, scene: Any, rate_hz: float = 20.0) -> None:
        self.scene = scene
        self.min_period_s = 1.0 / rate_hz
        self._last_draw = 0.0
        self._pending_state: Any = None
        self._lock = threading.Lock()
        self._last_utime = -1
        self._clock_reversals = 0
        self.warnings: list[str] = []

    def _warn(self, text: str) -> None:
        if text not in self.warnings:
            self.warnings.append(text)
            print(f"marionette view: warning: {text}", file=sys.stderr, flush=True)

    def _check_source(self, msg: Any) -> None:
        """Warns (once each) when ROBOT_STATE comes from another robot than the one drawn, or from
        two controllers at once (their clocks interleave)."""
        drawn = getattr(self.scene, "robot_name", None)
        if drawn is not None and msg.robot_name and msg.robot_name != drawn:
            self._warn(
                f"ROBOT_STATE comes from robot {msg.robot_name!r}, the view draws {drawn!r}: "
                f"restart it with --robot {msg.robot_name}"
            )
        if msg.utime < self._last_utime:
            self._clock_reversals += 1
            if self._clock_reversals >= 3:
                self._warn(
                    "two controllers publish ROBOT_STATE on this LCM URL "
                    "(their clocks interleave): give each run its own URL"
                )
        self._last_utime = msg.utime

    def subscribe(self, bus: LcmBus) -> None:
        bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self._on_state)
        bus.subscribe(
            channels.SIM_OBJECT_POSES, lcmt_object_poses, self._locked(self.scene.on_object_poses)
        )
        bus.subscribe(
            channels.OBJECT_POSES, lcmt_object_poses, self._locked(self.scene.on_object_poses)
        )
        bus.subscribe(
            channels.FOOTSTEP_PLAN, lcmt_footstep_plan, self._locked(self.scene.on_footstep_plan)
        )
        bus.subscribe(
            channels.SUPERVISOR_STATE,
            lcmt_supervisor_state,
            self._locked(self.scene.on_supervisor_state),
        )

    def _locked(self, draw):
        def handler(msg: Any) -> None:
            with self._lock:
                draw(msg)

        return handler

    def _on_state(self, msg: Any) -> None:
        self._check_source(msg)
        now = time.monotonic()
        self._pending_state = msg
        if now - self._last_draw >= self.min_period_s:
            self.flush()

    def flush(self) -> None:
        """Draws the latest robot state not drawn yet (the last one of a burst is never lost)."""
        msg, self._pending_state = self._pending_state, None
        if msg is not None:
            with self._lock:
                self.scene.on_robot_state(msg)
            self._last_draw = time.monotonic()


def serve(
    robot: str,
    scene: Path | None,
    lcm_url: str | None,
    url_file: Path | None,
    rate_hz: float = 20.0,
) -> int:
    """Runs the viewer until SIGINT/SIGTERM; returns the exit code."""
    from marionette.viewer.scene import ViewerScene

    server = MeshcatServer()
    stop = threading.Event()
    # SIGINT too: a KeyboardInterrupt in the middle of a meshcat request would leave its REQ
    # socket waiting for a reply, and the LCM thread's next draw would fail.
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        view = ViewerScene(server.visualizer(), robot, scene)
        node = ViewerNode(view, rate_hz)
        with LcmBus(lcm_url) as bus:
            node.subscribe(bus)
            bus.start()
            print(f"marionette view: open {server.web_url}", flush=True)
            if url_file is not None:  # written whole, then renamed: a reader never sees half of it
                tmp = Path(f"{url_file}.tmp")
                tmp.write_text(server.web_url + "\n")
                tmp.replace(url_file)
            while not stop.wait(node.min_period_s):
                node.flush()
            bus.stop()
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


def start_viewer(
    group: Any, robot: str, scene: Path | None, log: Any = print, timeout_s: float = 60.0
) -> str:
    """Starts ``marionette view`` in the run's ProcessGroup (same LCM URL, stopped with the
    group); returns the page's URL once the scene is ready."""
    url_file = group.log_dir / "viewer.url"
    url_file.unlink(missing_ok=True)
    argv = [
        sys.executable,
        "-m",
        "marionette.cli",
        "view",
        "--robot",
        robot,
        "--url-file",
        url_file,
    ]
    if scene is not None:
        argv += ["--scene", scene]
    group.start("viewer", argv)
    deadline = time.monotonic() + timeout_s
    while not url_file.is_file():
        group.check_alive()
        if time.monotonic() > deadline:
            raise RuntimeError(
                f"the viewer gave no URL within {timeout_s} s (log: {group.log_dir / 'viewer.log'})"
            )
        time.sleep(0.1)
    url = url_file.read_text().strip()
    log(f"viewer: open {url}")
    return url
