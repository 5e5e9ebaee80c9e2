"""What a campaign asks of the engine that runs its trials (:mod:`.local`: child processes on
this machine; :mod:`.ray_cluster`: tasks on a Ray cluster)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from marionette.campaigns.trial import TrialOutcome, TrialSpec


@dataclass
class Running:
    """A trial running now: where, since when (``time.time()`` of the machine that reports it),
    which attempt (a killed worker's trial is retried) and the worker process's pid."""

    host: str
    since: float
    attempt: int = 1
    pid: int = 0


@dataclass
class Finished:
    """A trial the engine is done with: its outcome and the driver's folder holding what it left
    (the report folder ``outcome.folder`` and trial.log). ``transfer_s``: [s] on a cluster, from
    the end of the trial's process to its files unpacked on the driver."""

    spec: TrialSpec
    outcome: TrialOutcome
    work_dir: Path
    attempts: int = 1
    transfer_s: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)


class Backend(Protocol):
    """Runs submitted trials, as many at once as it can."""

    #: How many trials run at once (for the ETA and the overhead figures).
    slots: int
    #: How the report names the engine ("2 jobs on this machine", "Ray cluster at ...").
    description: str

    def submit(self, spec: TrialSpec, work_dir: Path) -> None:
        """Queues a trial; what it leaves ends up in ``work_dir`` on the driver."""

    def poll(self, timeout_s: float) -> list[Finished]:
        """The trials finished since the last call (waits up to ``timeout_s`` for one)."""

    def running(self) -> dict[int, Running]:
        """Trial seed -> where it runs now."""

    def close(self, interrupted: bool) -> None:
        """Stops: running trials are interrupted (they write partial reports) when
        ``interrupted``, else they were all polled."""
