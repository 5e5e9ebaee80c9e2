"""``--jobs K``: K trials at once on this machine, each a ``marionette demo`` child process with
its own report folder (and, through the demo's harness, its own private LCM URL and processes)."""

from __future__ import annotations

import queue
import signal
import socket
import subprocess
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from marionette.campaigns.backend import Finished, Running
from marionette.campaigns.trial import TrialSpec, run_trial


class LocalPool:
    """Runs trials in ``jobs`` threads, each waiting on one trial's process."""

    def __init__(self, jobs: int) -> None:
        self.slots = jobs
        self.description = f"{jobs} job{'s' if jobs > 1 else ''} on {socket.gethostname()}"
        self._pool = ThreadPoolExecutor(max_workers=jobs, thread_name_prefix="trial")
        self._done: queue.Queue[Finished] = queue.Queue()
        self._lock = threading.Lock()
        self._running: dict[int, Running] = {}
        self._processes: dict[int, subprocess.Popen] = {}

    def submit(self, spec: TrialSpec, work_dir: Path) -> None:
        self._pool.submit(self._run, spec, work_dir)

    def _run(self, spec: TrialSpec, work_dir: Path) -> None:
        def started(popen: subprocess.Popen) -> None:
            with self._lock:
                self._processes[spec.seed] = popen
                self._running[spec.seed] = Running(socket.gethostname(), time.time(), 1, popen.pid)

        try:
            outcome = run_trial(spec, work_dir, started)
        finally:
            with self._lock:
                self._processes.pop(spec.seed, None)
                self._running.pop(spec.seed, None)
        self._done.put(Finished(spec, outcome, work_dir))

    def poll(self, timeout_s: float) -> list[Finished]:
        out = []
        try:
            out.append(self._done.get(timeout=timeout_s))
            while True:
                out.append(self._done.get_nowait())
        except queue.Empty:
            pass
        return out

    def running(self) -> dict[int, Running]:
        with self._lock:
            return dict(self._running)

    def close(self, interrupted: bool) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        if interrupted:
            with self._lock:
                processes = list(self._processes.values())
            for p in processes:  # the demo writes its partial report and stops its processes
                p.send_signal(signal.SIGINT)
        self._pool.shutdown(wait=True)
