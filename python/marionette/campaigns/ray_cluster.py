"""``--cluster ADDRESS``: each trial is a Ray task (one CPU) that runs the whole stack of the
trial on a worker — the trial's ``marionette demo`` child process with its controller, logger and
planners, in a temporary folder of the worker — and returns the trial's files (a gzip'd tar of
its report folder and ``trial.log``), unpacked on the driver.

Every node of the cluster runs this marionette: the same checkout (or install) with its C++
build, ``PYTHONPATH`` and ``MARIONETTE_BUILD_DIR`` set in the environment of ``ray start``. The
plan cache is each node's own (``$MARIONETTE_PLAN_CACHE`` may point at a shared folder: it is safe
for concurrent writers on one machine and on NFS with working locks).

A worker that dies (killed, its node lost) fails its task; Ray runs it again up to ``retries``
times (``max_retries``), and a trial that still has no result is reported as lost with Ray's
reason (and run again when the campaign is resumed). Tasks report their start to a small actor
(:class:`TrialBoard`): the driver's progress shows where each trial runs and which attempt it is.
"""

from __future__ import annotations

import logging
import os
import shutil
import socket
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

from marionette.campaigns.backend import Finished, Running
from marionette.campaigns.errors import CampaignError
from marionette.campaigns.trial import TrialOutcome, TrialSpec, pack, run_trial, unpack


class TrialBoard:
    """A Ray actor: each task's start (host, pid, time), per trial seed."""

    def __init__(self) -> None:
        self.starts: dict[int, list[tuple[str, int, float]]] = {}

    def started(self, seed: int, host: str, pid: int, when: float) -> None:
        self.starts.setdefault(seed, []).append((host, pid, when))

    def snapshot(self) -> dict[int, list[tuple[str, int, float]]]:
        return self.starts


def trial_task(spec: dict[str, Any], board: Any) -> tuple[dict[str, Any], bytes, float]:
    """Runs on a worker: one trial in a temporary folder; returns its outcome, its files and
    the time (``time.time()``) its process ended."""
    trial = TrialSpec(**spec)
    board.started.remote(trial.seed, socket.gethostname(), os.getpid(), time.time())
    work = Path(tempfile.mkdtemp(prefix=f"marionette-trial-{trial.seed}-"))
    try:
        outcome = run_trial(trial, work)
        ended = time.time()
        return outcome.to_dict(), pack(work), ended
    finally:
        shutil.rmtree(work, ignore_errors=True)


class RayCluster:
    """Trials as Ray tasks on the cluster at ``address`` (``HOST:PORT`` of its head, ``auto``,
    or ``ray://HOST:PORT`` through Ray Client)."""

    def __init__(self, address: str, retries: int) -> None:
        try:
            import ray
        except ImportError as e:
            raise CampaignError(
                "--cluster needs Ray: pip install 'ray[client]' (scripts/requirements.txt)"
            ) from e
        self._ray = ray
        try:
            with warnings.catch_warnings():  # Ray's tips about its future defaults
                warnings.simplefilter("ignore", FutureWarning)
                ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise CampaignError(f"cannot connect to the Ray cluster at {address!r}: {e}") from e
        cpus = int(ray.cluster_resources().get("CPU", 0))
        if cpus < 1:
            ray.shutdown()
            raise CampaignError(
                f"the Ray cluster at {address!r} has no CPU to run trials on (start its workers "
                "with `ray start --address HEAD --num-cpus N`)"
            )
        self.slots = cpus
        nodes = sum(1 for n in ray.nodes() if n.get("Alive") and n["Resources"].get("CPU", 0) > 0)
        self.description = f"Ray cluster at {address} ({nodes} nodes, {cpus} CPUs)"
        self._board: Any = ray.remote(num_cpus=0)(TrialBoard).remote()  # an actor handle
        self._task = ray.remote(num_cpus=1, max_retries=retries, retry_exceptions=False)(trial_task)
        self._refs: dict[Any, tuple[TrialSpec, Path]] = {}
        self._closed = False
        self._starts: dict[int, list[tuple[str, int, float]]] = {}

    def submit(self, spec: TrialSpec, work_dir: Path) -> None:
        self._refs[self._task.remote(spec.to_dict(), self._board)] = (spec, work_dir)

    def poll(self, timeout_s: float) -> list[Finished]:
        ray = self._ray
        if self._closed or not self._refs:
            time.sleep(timeout_s)
            return []
        ready, _ = ray.wait(list(self._refs), num_returns=1, timeout=timeout_s)
        if ready:
            ready, _ = ray.wait(list(self._refs), num_returns=len(self._refs), timeout=0)
        self._refresh_starts()
        return [self._collect(ref) for ref in ready]

    def _collect(self, ref: Any) -> Finished:
        ray = self._ray
        spec, work_dir = self._refs.pop(ref)
        attempts = max(1, len(self._starts.get(spec.seed, [])))
        try:
            outcome_dict, data, ended = ray.get(ref)
        except ray.exceptions.RayError as e:
            first = (str(e).strip().splitlines() or [type(e).__name__])[0]
            starts = self._starts.get(spec.seed, [])
            host = starts[-1][0] if starts else "?"
            reason = f"Ray: {type(e).__name__} after {attempts} attempt(s): {first}"
            return Finished(
                spec,
                TrialOutcome(spec.seed, host, None, 0.0, None, False, reason),
                work_dir,
                attempts,
            )
        unpack(data, work_dir)
        return Finished(
            spec,
            TrialOutcome(**outcome_dict),
            work_dir,
            attempts,
            transfer_s=max(0.0, time.time() - ended),
            extra={"bytes": float(len(data))},
        )

    def _refresh_starts(self) -> None:
        try:
            self._starts = self._ray.get(self._board.snapshot.remote(), timeout=5.0)
        except self._ray.exceptions.RayError:
            pass  # the progress line shows the last snapshot

    def running(self) -> dict[int, Running]:
        if self._closed:
            return {}
        pending = {spec.seed for spec, _ in self._refs.values()}
        return {
            seed: Running(starts[-1][0], starts[-1][2], len(starts), starts[-1][1])
            for seed, starts in self._starts.items()
            if seed in pending and starts
        }

    def close(self, interrupted: bool) -> None:
        ray = self._ray
        if interrupted:
            for ref in self._refs:  # the worker is killed; its trial gets SIGTERM and stops
                ray.cancel(ref, force=True)
        self._closed = True
        ray.shutdown()
