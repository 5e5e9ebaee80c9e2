"""Start and stop the processes of a run (controller, planners, perception, logger) as a group.

Every process gets the same private LCM URL through ``MARIONETTE_LCM_URL``, writes its output to
``<log_dir>/<name>.log``, and is stopped (SIGINT, then SIGKILL after a grace period) when the group
closes, whatever happened in between — a demo or a test never leaves a process behind.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import marionette

# The silence after which a controller started beside its supervisor holds the robot (its
# --supervisor-timeout). A demo's trial or dry run puts the simulated robot, the controller,
# perception and the supervisor on one shared machine, and under load that machine stops a whole
# process for longer than the controller's default 100 ms: a plank-flip trial at load 3.7 on 2
# cores left 250 ms between two beats of its heartbeat thread (C++, which the interpreter's lock
# cannot hold back) and was held as silent. A robot's supervisor on a machine of its own keeps
# the default; a dead supervisor still stops the robot within this.
SHARED_MACHINE_SUPERVISOR_TIMEOUT_S = 0.5


def restore_stop_signals() -> None:
    """Lets this process hear SIGINT and SIGTERM, however its parent left them: unblocked, and
    given their default action back where they were ignored (SIGINT: KeyboardInterrupt). A signal
    mask and ignored signals survive fork and exec; a Ray worker blocks SIGINT and a
    non-interactive shell ignores it in ``command &``. A process started so did not hear the
    group's stop (SIGINT), was killed after the grace period (5 s each: a trial on a Ray cluster
    took twice as long as the same trial run by ``--jobs``) and lost what it had not written.
    Called first by every marionette program (C++: ``runtime::RestoreStopSignals``)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    if threading.current_thread() is not threading.main_thread():
        return  # dispositions are set from the main thread only (a test calling main())
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if signal.getsignal(signal.SIGTERM) == signal.SIG_IGN:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


class ProcessError(RuntimeError):
    """A process of the group could not start or died while it was needed."""


@dataclass
class ManagedProcess:
    name: str
    argv: list[str]
    log_path: Path
    popen: subprocess.Popen

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log_tail(self, lines: int = 20) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"


@dataclass
class ProcessGroup:
    """Processes sharing one LCM URL; use as a context manager."""

    lcm_url: str
    log_dir: Path
    env: dict[str, str] = field(default_factory=dict)
    processes: list[ManagedProcess] = field(default_factory=list)
    _previous_sigterm: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.log_dir = Path(self.log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)

    def environment(self) -> dict[str, str]:
        env = dict(os.environ)
        env.update(self.env)
        env["MARIONETTE_LCM_URL"] = self.lcm_url
        env["MARIONETTE_BUILD_DIR"] = str(marionette.BUILD_DIR)
        env.setdefault("EGL_PLATFORM", "surfaceless")
        return env

    def start(self, name: str, argv: Sequence[str], cwd: Path | None = None) -> ManagedProcess:
        """Starts ``argv`` with its output in ``<log_dir>/<name>.log``."""
        log_path = self.log_dir / f"{name}.log"
        log = open(log_path, "w")
        try:
            popen = subprocess.Popen(
                list(map(str, argv)),
                stdout=log,
                stderr=subprocess.STDOUT,
                env=self.environment(),
                cwd=str(cwd or marionette.REPO_ROOT),
                start_new_session=True,  # our signals reach it, a terminal's Ctrl-C does not twice
            )
        except OSError as exc:
            log.close()
            raise ProcessError(f"cannot start {name} ({argv[0]}): {exc}") from exc
        proc = ManagedProcess(name, list(map(str, argv)), log_path, popen)
        self.processes.append(proc)
        return proc

    def check_alive(self) -> None:
        """Raises ProcessError naming the first process that exited, with its log's tail. The
        first line ends with the log's last line, usually the reason: reports and campaign tables
        keep only that line, and the log may be in a trial's working folder removed after it."""
        for p in self.processes:
            if not p.alive():
                tail = p.log_tail()
                last = next((line for line in reversed(tail.splitlines()) if line.strip()), "")
                raise ProcessError(
                    f"{p.name} exited with code {p.popen.returncode}"
                    + (f": {last.strip()}" if last else " (its log is empty)")
                    + f"\nlast lines of {p.log_path}:\n{tail}"
                )

    def stop(self, name: str, timeout_s: float = 5.0) -> int | None:
        """Stops one process (SIGINT, then SIGKILL); returns its exit code."""
        for p in self.processes:
            if p.name == name:
                return _stop(p, timeout_s)
        raise KeyError(name)

    def close(self, timeout_s: float = 5.0) -> None:
        for p in reversed(self.processes):
            _stop(p, timeout_s)

    def __enter__(self) -> ProcessGroup:
        # SIGTERM (`timeout`, `kill`, a cancelled job) ends Python without unwinding, and the
        # processes, each in its own session, would outlive it: while the group is open it raises
        # SystemExit instead, so that __exit__ stops them.
        if threading.current_thread() is threading.main_thread():
            self._previous_sigterm = signal.signal(signal.SIGTERM, _exit_on_sigterm)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous_sigterm is not None:
            # A further SIGTERM must not cut the stop short and leave the rest running: a
            # process started under PR_SET_PDEATHSIG gets one per thread of its dying parent.
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        try:
            self.close()
        finally:
            if self._previous_sigterm is not None:
                signal.signal(signal.SIGTERM, self._previous_sigterm)
                self._previous_sigterm = None


def _exit_on_sigterm(signum: int, frame: object) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # once: the group's __exit__ stops it all
    raise SystemExit(128 + signum)


def _stop(p: ManagedProcess, timeout_s: float) -> int | None:
    if p.alive():
        try:
            os.killpg(p.popen.pid, signal.SIGINT)
        except ProcessLookupError:
            pass
        deadline = time.monotonic() + timeout_s
        while p.alive() and time.monotonic() < deadline:
            time.sleep(0.02)
        if p.alive():
            try:
                os.killpg(p.popen.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.popen.wait(timeout=5.0)
    return p.popen.returncode
