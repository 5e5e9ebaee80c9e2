"""A campaign: trials of one scenario with seeds S, S+1, ..., run by an engine (:mod:`.local`,
:mod:`.ray_cluster`), gathered in one folder and reported as they finish.

The campaign folder::

    campaign.json          the settings (a resumed campaign must have the same ones)
    trials/seed<S>/        each finished trial: its report folder (report.json, report.md,
                           plots, run.lcmlog, logs/), trial.log (the demo's output) and
                           trial.json (how it ran: host, wall time, attempts)
    attempts/seed<S>-<k>/  what a lost trial left (no complete report): kept to diagnose it
    progress.json          live: finished, running (where, which attempt), queued, ETA
    report.json, report.md, *.png   the campaign report (:mod:`.report`)

A trial's folder appears in ``trials/`` whole (renamed into place once its report is complete),
so a campaign resumed with the same ``--campaign`` folder runs only the seeds without one; a lost
trial is run again.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from marionette.campaigns.backend import Backend, Finished, Running
from marionette.campaigns.errors import CampaignError
from marionette.campaigns.report import TrialRow, aggregate, write_campaign_report
from marionette.campaigns.trial import LOG, TrialSpec, complete_report
from marionette.scenarios.base import Scenario
from marionette.scenarios.report import write_json

SETTINGS_FILE = "campaign.json"
RUN_FILE = "trial.json"
PROGRESS_PERIOD_S = 15.0  # a progress line at least this often
PLOTS_PERIOD_S = 120.0  # the PNGs redrawn at most this often while trials finish


@dataclass(frozen=True)
class CampaignSettings:
    """What every trial of the campaign shares (``marionette demo`` options) and its seeds."""

    scenario: str  # as `marionette demo` takes it: a name or a declaration file
    first_seed: int
    trials: int
    plan_seed: int | None = None
    perturb: str = "none"
    speed: float = 1.0
    gripper_admittance: bool | None = None
    controller_url: str | None = None
    dry_run: bool = True  # the controllers played on the plan before anything moves
    split_sim: bool = (
        False  # the robot simulated in marionette-sim, driven over the driver protocol
    )

    def seeds(self) -> range:
        return range(self.first_seed, self.first_seed + self.trials)

    def spec(self, seed: int) -> TrialSpec:
        return TrialSpec(
            self.scenario,
            seed,
            self.plan_seed,
            self.perturb,
            self.speed,
            self.gripper_admittance,
            self.controller_url,
            self.dry_run,
            self.split_sim,
        )

    def same_trials_as(self, other: CampaignSettings) -> list[str]:
        """The settings (but the number of trials and the controller URL) that differ."""
        mine, theirs = asdict(self), asdict(other)
        return [k for k in mine if k not in ("trials", "controller_url") and mine[k] != theirs[k]]


class Campaign:
    """The campaign in ``folder`` (module docstring) of ``settings`` on ``scenario``."""

    def __init__(
        self,
        folder: Path,
        settings: CampaignSettings,
        scenario: Scenario,
        log: Callable[[str], None] = print,
    ) -> None:
        self.folder, self.settings, self.scenario, self.log = Path(folder), settings, scenario, log
        self.trials_dir = self.folder / "trials"
        self.lost: dict[int, TrialRow] = {}
        self.engine = ""
        self.wall_s = 0.0
        self._last_plots = 0.0

    # -- folder ----------------------------------------------------------------------------

    def prepare(self) -> list[int]:
        """Creates or checks the campaign folder; returns the seeds still to run. CampaignError
        when the folder holds a campaign of other settings."""
        path = self.folder / SETTINGS_FILE
        if path.exists():
            try:
                before = CampaignSettings(**json.loads(path.read_text())["settings"])
            except (ValueError, TypeError, KeyError) as e:
                raise CampaignError(f"{path} is not a campaign's settings file: {e}") from e
            differ = self.settings.same_trials_as(before)
            if differ:
                raise CampaignError(
                    f"{self.folder} holds a campaign with other settings ("
                    + ", ".join(f"{k} {getattr(before, k)!r}" for k in differ)
                    + "): give another --campaign folder, or the same settings to resume it"
                )
            if before.trials > self.settings.trials:
                self.settings = replace(self.settings, trials=before.trials)
        self.trials_dir.mkdir(parents=True, exist_ok=True)
        write_json(path, {"settings": asdict(self.settings)})
        done = self.finished_seeds()
        return [s for s in self.settings.seeds() if s not in done]

    def trial_folder(self, seed: int) -> Path:
        return self.trials_dir / f"seed{seed}"

    def finished_seeds(self) -> set[int]:
        """The seeds whose trial folder holds a complete report."""
        return {
            s for s in self.settings.seeds() if complete_report(self.trial_folder(s)) is not None
        }

    def work_dir(self, seed: int) -> Path:
        """Where a trial runs (local jobs) or its files are unpacked (cluster): emptied first."""
        work = self.trials_dir / ".work" / f"seed{seed}"
        shutil.rmtree(work, ignore_errors=True)
        return work

    def keep(self, finished: Finished) -> TrialRow:
        """Moves a finished trial's files to ``trials/seed<S>`` (complete) or
        ``attempts/seed<S>-<k>`` (lost) and returns its row."""
        o, work = finished.outcome, finished.work_dir
        run = {
            "host": o.host,
            "started": o.started,
            "wall_s": o.wall_s,
            "exit_code": o.exit_code,
            "attempts": finished.attempts,
            "transfer_s": finished.transfer_s,
            **finished.extra,
        }
        if o.complete and o.folder is not None:
            src = work / o.folder
            if (work / LOG).exists():
                os.replace(work / LOG, src / LOG)
            write_json(src / RUN_FILE, {"seed": o.seed, "engine": self.engine, **run})
            dest = self.trial_folder(o.seed)
            shutil.rmtree(dest, ignore_errors=True)  # a folder without a complete report
            os.rename(src, dest)
            shutil.rmtree(work, ignore_errors=True)
            return self.row(o.seed)
        attempts = self.folder / "attempts"
        attempts.mkdir(exist_ok=True)
        k = 1 + sum(1 for _ in attempts.glob(f"seed{o.seed}-*"))
        dest = attempts / f"seed{o.seed}-{k}"
        if work.exists():
            os.rename(work, dest)
        row = TrialRow(o.seed, "lost", o.reason, None, None, run)
        self.lost[o.seed] = row
        return row

    def row(self, seed: int) -> TrialRow:
        """The report's row of trial ``seed`` from its folder (or lost, or pending)."""
        folder = self.trial_folder(seed)
        report = complete_report(folder)
        if report is None:
            return self.lost.get(seed, TrialRow(seed, "pending"))
        try:
            run = json.loads((folder / RUN_FILE).read_text())
        except (OSError, ValueError):
            run = {}
        status = "succeeded" if report["success"] else "failed"
        return TrialRow(
            seed,
            status,
            "" if report["success"] else self.failure_reason(report),
            str(folder.relative_to(self.folder)),
            report,
            run,
            self.scenario.draw(report),
        )

    def failure_reason(self, report: dict[str, Any]) -> str:
        if report.get("stopped"):
            return "stopped: " + str(report["stopped"]).strip().splitlines()[0]
        try:
            return self.scenario.failure_reason(report) or "failed"
        except (KeyError, TypeError, IndexError):
            return str(report.get("summary", "failed"))

    # -- report ----------------------------------------------------------------------------

    def write_report(self, final: bool) -> dict[str, Any]:
        rows = [self.row(s) for s in self.settings.seeds()]
        report = aggregate(
            rows,
            {
                **asdict(self.settings),
                "scenario_name": self.scenario.name,
                "engine": self.engine,
                "wall_s": self.wall_s,
            },
        )
        plots = final or time.monotonic() - self._last_plots > PLOTS_PERIOD_S
        if plots:
            self._last_plots = time.monotonic()
        write_campaign_report(self.folder, report, plots=plots)
        return report

    # -- run -------------------------------------------------------------------------------

    def run(self, backend: Backend) -> dict[str, Any]:
        """Runs the trials still to run on ``backend``, reporting as they finish; returns the
        campaign report. Ctrl-C stops the running trials (their partial reports kept in
        attempts/) and writes the report of what finished, then raises KeyboardInterrupt."""
        seeds = self.prepare()
        self.engine = backend.description
        already = self.settings.trials - len(seeds)
        self.log(
            f"campaign {self.folder}: {self.settings.trials} trials of {self.scenario.name} on "
            f"{self.engine}"
            + (f"; {already} already finished (resumed), {len(seeds)} to run" if already else "")
        )
        t0 = time.monotonic()
        for seed in seeds:
            backend.submit(self.settings.spec(seed), self.work_dir(seed))
        outstanding = set(seeds)
        progress = Progress(self, len(seeds), t0, backend.slots)
        interrupted = False
        try:
            while outstanding:
                for finished in backend.poll(1.0):
                    row = self.keep(finished)
                    outstanding.discard(finished.spec.seed)
                    progress.finished(row)
                    self.wall_s = time.monotonic() - t0
                    self.write_report(final=False)
                progress.show(backend.running(), len(outstanding))
        except KeyboardInterrupt:
            interrupted = True
            raise
        finally:
            backend.close(interrupted)
            self.wall_s = time.monotonic() - t0
            for finished in backend.poll(0.0):  # interrupted trials: their files are kept
                self.keep(finished)
            report = self.write_report(final=True)
            progress.show(backend.running(), 0, force=True)
        return report


class Progress:
    """The progress lines (done / running / failed, ETA) and ``progress.json``."""

    def __init__(self, campaign: Campaign, to_run: int, t0: float, slots: int) -> None:
        self.campaign, self.to_run, self.t0, self.slots = campaign, to_run, t0, slots
        self.done = 0
        self.walls: list[float] = []  # [s] the trials finished in this session
        self.counts = {"succeeded": 0, "failed": 0, "lost": 0}
        self._last_state: tuple = (-1, -1, [])
        self._last_counts: tuple = (-1, -1)
        self._last_time = 0.0

    def finished(self, row: TrialRow) -> None:
        self.done += 1
        if row.run.get("wall_s"):
            self.walls.append(float(row.run["wall_s"]))
        self.counts[row.status] = self.counts.get(row.status, 0) + 1
        what = row.status.upper() if row.status != "succeeded" else "ok"
        wall = row.run.get("wall_s") or 0.0
        self.campaign.log(
            f"  trial {row.seed}: {what} in {wall:.0f} s on {row.run.get('host', '?')}"
            + (f" ({row.run['attempts']} attempts)" if (row.run.get("attempts") or 1) > 1 else "")
            + (f": {row.reason}" if row.reason else "")
        )

    def eta_s(self, running: dict[int, Running], queued: int) -> float | None:
        """The work left, at the mean wall time of the trials finished so far (what the running
        ones have done counted), shared by the engine's slots."""
        if not self.walls:
            return None
        mean = sum(self.walls) / len(self.walls)
        now = time.time()
        left = sum(max(0.0, mean - (now - r.since)) for r in running.values()) + queued * mean
        return left / max(1, self.slots)

    def show(self, running: dict[int, Running], queued: int, force: bool = False) -> None:
        """A progress line when something changed (at least every PROGRESS_PERIOD_S);
        progress.json whenever what runs where changed."""
        now = time.monotonic()
        queued = max(0, queued - len(running))
        eta = self.eta_s(running, queued)
        state = {
            "done": self.done,
            "to_run": self.to_run,
            **self.counts,
            "queued": queued,
            "running": [{"seed": s, **asdict(r)} for s, r in sorted(running.items())],
        }
        where = [(s, r.host, r.pid, r.attempt) for s, r in sorted(running.items())]
        if force or (self.done, queued, where) != self._last_state:
            write_json(
                self.campaign.folder / "progress.json",
                {**state, "elapsed_s": now - self.t0, "eta_s": eta},
            )
        line = (
            f"[campaign] {self.done}/{self.to_run} done ({self.counts['succeeded']} ok, "
            f"{self.counts['failed']} failed, {self.counts['lost']} lost), {len(running)} "
            f"running, {queued} queued; {_duration(now - self.t0)} elapsed"
            + (f", ETA {_duration(eta)}" if eta is not None else "")
        )
        counts = (self.done, len(running), queued)
        if force or counts != self._last_counts or now - self._last_time > PROGRESS_PERIOD_S:
            self.campaign.log(line)
            self._last_time = now
        self._last_state, self._last_counts = (self.done, queued, where), counts


def _duration(s: float) -> str:
    s = round(s)
    return f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"
