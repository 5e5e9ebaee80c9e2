"""The one start-up, run and teardown sequence of a scenario's trial.

:func:`harness` opens a private LCM URL (or the ``--controller-url`` of a running controller)
and starts, in one process group whose outputs go to ``<report folder>/logs/``:

1. ``marionette-logger`` recording every message to ``run.lcmlog`` (camera frames left out when the
   controller renders cameras: 1.5 MB each, the poses measured in them are logged);
2. ``marionette-controller`` on the trial's scene (unless a running one is driven) — with
   ``--split-sim``, ``marionette-sim`` on the scene and the controller driving it as it would a
   robot (``--backend driver``, docs/driver.md);
3. ``marionette perceive`` when the scenario measures objects with a camera;

waits for the controller's first state, serves the browser 3D view on ``--view``, and yields a
:class:`Run`. Further processes (the footstep planner) start from :meth:`Run.start_cli`. On a
normal exit it records the controller's summary in ``report["controller"]`` and checks that
every process still runs; in every case it stops the processes (Ctrl-C included: the partial
report is then written by :meth:`.base.Scenario.run`).
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import marionette
from marionette.control.client import ControllerClient
from marionette.control.replay_cli import JOURNAL_NAME
from marionette.lcm_bus import logger_command, private_lcm_url, udp_receive_buffer_drops
from marionette.processes import (
    SHARED_MACHINE_SUPERVISOR_TIMEOUT_S,
    ManagedProcess,
    ProcessError,
    ProcessGroup,
)
from marionette.robots import controller_robot_argument
from marionette.scenarios.base import RunOptions, ScenarioError, repo_relative
from marionette.scenarios.report import controller_summary, heartbeat_summary

READY_TIMEOUT_S = 60.0  # the controller's first state (MuJoCo scene load, camera set-up)


@dataclass(frozen=True)
class Processes:
    """What a trial runs beside itself. ``scene``: the MJCF the controller loads (a perturbed copy
    of the scenario's); ``view_scene``: the one the browser view draws (default ``scene``);
    ``perceive``: the arguments of ``marionette perceive`` after ``--lcm-url`` (None: no
    perception process); ``sim_args``: options of the simulated robot (its camera's noise, its
    encoders' offsets), given to whichever process simulates it: the controller, or
    marionette-sim."""

    robot: str
    scene: Path
    camera_rate: float = 0.0  # [Hz of controller time] camera frames the controller renders
    status_rate: int = 100  # [Hz] CONTROLLER_STATUS
    sim_args: tuple[str, ...] = ()
    perceive: tuple[str, ...] | None = None
    view_scene: Path | None = None


# With --split-sim, the silence after which the controller holds for want of robot states, and
# the simulated robot holds for want of commands: the defaults (10 ms) are a robot's, whose driver
# and controller have their cores; a trial's share two cores with the supervisor and perception.
TRIAL_DRIVER_TIMEOUT_S = 0.5


def controller_command(
    processes: Processes, url: str, speed: float, split_sim: bool = False
) -> list[Any]:
    """The marionette-controller command line of a trial: simulating the robot itself, or
    (``split_sim``) driving marionette-sim's (:func:`sim_command`)."""
    common = [
        marionette.BUILD_DIR / "marionette-controller",
        "--lcm-url",
        url,
        "--robot",
        controller_robot_argument(processes.robot),
        "--speed",
        str(speed),
        "--status-rate",
        str(processes.status_rate),
        "--supervisor-timeout",
        str(SHARED_MACHINE_SUPERVISOR_TIMEOUT_S),
    ]
    if split_sim:
        return [*common, "--backend", "driver", "--driver-timeout", str(TRIAL_DRIVER_TIMEOUT_S)]
    scene = ["--scene", processes.scene, "--camera-rate", str(processes.camera_rate)]
    return [*common, *scene, *processes.sim_args]


def sim_command(processes: Processes, url: str, speed: float) -> list[Any]:
    """The marionette-sim command line of a trial run with --split-sim: the scene, its camera and
    the simulated robot's options, a driver on ``url``."""
    return [
        marionette.BUILD_DIR / "marionette-sim",
        "--lcm-url",
        url,
        "--robot",
        controller_robot_argument(processes.robot),
        "--scene",
        processes.scene,
        "--speed",
        str(speed),
        "--camera-rate",
        str(processes.camera_rate),
        "--command-timeout",
        str(TRIAL_DRIVER_TIMEOUT_S),
        *processes.sim_args,
    ]


class Run:
    """A running trial: its process group, controller client, LCM URL, report and timings."""

    def __init__(
        self,
        group: ProcessGroup,
        client: ControllerClient,
        url: str,
        report: dict[str, Any],
        log: Callable[[str], None],
    ) -> None:
        self.group, self.client, self.url, self.report, self.log = group, client, url, report, log

    def start_cli(self, name: str, args: list[str]) -> ManagedProcess:
        """Starts ``marionette <args>`` (this interpreter) as process ``name`` of the group."""
        return self.group.start(name, [sys.executable, "-m", "marionette.cli", *args])

    def wait(
        self, condition: Callable[[ControllerClient], bool], timeout_s: float, what: str
    ) -> None:
        """``client.wait`` in 1 s slices, checking that every process still runs: a process that
        died fails the trial with its log at once, not after the timeout. ScenarioError."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.client.wait(condition, min(1.0, max(0.01, deadline - time.monotonic())), what)
                return
            except TimeoutError as e:
                try:
                    self.group.check_alive()
                except ProcessError as dead:
                    raise ScenarioError(f"waiting for {what}: {dead}") from dead
                if time.monotonic() >= deadline:  # the message names the whole wait, not a slice
                    raise ScenarioError(self.client.timeout_message(timeout_s, what)) from e


@contextlib.contextmanager
def harness(
    out_dir: Path, processes: Processes, options: RunOptions, report: dict[str, Any]
) -> Iterator[Run]:
    """Starts the trial's processes, yields the :class:`Run` once the controller is ready, stops
    them (module docstring). Records in ``report``: ``lcm_url``; ``scene``, the scene a viewer
    draws (``marionette replay --view``); ``controller_scene``, the one the controller loads
    (unless a running controller is driven); with ``--view``, ``viewer_url``."""
    url = options.controller_url or private_lcm_url()
    report["lcm_url"] = url
    report["scene"] = repo_relative(processes.view_scene or processes.scene)
    if options.controller_url is None:
        report["controller_scene"] = repo_relative(processes.scene)
        report["simulator"] = (
            "marionette-sim (a driver process)"
            if options.split_sim
            else ("in the controller's process")
        )
    cameras = processes.camera_rate > 0
    drops_before = udp_receive_buffer_drops()
    with ProcessGroup(url, out_dir / "logs") as group, ControllerClient(url) as client:
        group.start(
            "logger",
            logger_command(url, out_dir / "run.lcmlog", exclude="^CAMERA_" if cameras else None),
        )
        if options.controller_url is None:
            if options.split_sim:
                group.start("sim", sim_command(processes, url, options.speed))
            # Its own journal beside run.lcmlog: what `marionette replay --controller` needs,
            # even if the log misses a message.
            journal = ("--journal", str(out_dir / JOURNAL_NAME))
            command = controller_command(processes, url, options.speed, options.split_sim)
            group.start("controller", [*command, *journal])
        run = Run(group, client, url, report, options.log)
        if processes.perceive is not None:
            run.start_cli("perceive", ["perceive", "--lcm-url", url, *processes.perceive])
        if options.controller_url is not None:  # another machine's: say what is awaited
            options.log(
                f"waiting up to {READY_TIMEOUT_S:.0f} s for the marionette-controller on "
                f"{url} (start it there, or run without --controller-url)"
            )
        client.wait_ready(READY_TIMEOUT_S, processes=group)
        if options.view:  # the browser 3D view of the run, stopped with the group
            from marionette.viewer.node import start_viewer

            report["viewer_url"] = start_viewer(
                group, processes.robot, processes.view_scene or processes.scene, options.log
            )
        yield run
        report["controller"] = controller_summary(client.status)
        if client.bus.heartbeat is not None:
            report["heartbeat"] = heartbeat_summary(client.bus.heartbeat)
        group.check_alive()
    _report_udp_drops(drops_before, report, options.log)


def _report_udp_drops(
    before: int | None, report: dict[str, Any], log: Callable[[str], None]
) -> None:
    """Records in ``report`` the datagrams the kernel dropped for lack of receive buffer while
    the trial ran (machine-wide: another program's count in too), and says so when any were:
    the processes, and the LCM log, may have missed messages."""
    after = udp_receive_buffer_drops()
    if before is None or after is None:
        return
    report["udp_receive_buffer_drops"] = after - before
    if after > before:
        with open("/proc/sys/net/core/rmem_max") as f:
            rmem_max = f.read().strip()
        log(
            f"LCM: the kernel dropped {after - before} UDP datagrams for lack of receive buffer "
            f"during the run (net.core.rmem_max = {rmem_max} bytes): processes and run.lcmlog "
            "may miss messages; scripts/setup raises the buffers to 16 MiB (as root)"
        )
