"""The campaign driver without running the stack: an engine that writes each trial's report as a
trial would (random verdicts and criteria, a trial lost now and then) — the campaign folder, the
report against the trials' own reports, resume, lost trials, settings that cannot be mixed."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from marionette.campaigns import Campaign, CampaignError, CampaignSettings
from marionette.campaigns.backend import Finished, Running
from marionette.campaigns.report import label, reason_group, unit_of, worse_when
from marionette.campaigns.trial import TrialOutcome, TrialSpec
from marionette.scenarios import SCENARIOS
from marionette.scenarios.report import write_json

UR10_BOX = SCENARIOS["ur10-box"]


class ScriptedEngine:
    """Runs nothing: writes the report folder a plan-and-execute trial would, its verdict drawn
    from the seed; the seeds of ``lost`` die without a report."""

    slots = 2
    description = "scripted engine"

    def __init__(self, lost: set[int] = frozenset()) -> None:
        self.lost = set(lost)
        self.submitted: list[int] = []
        self._queue: list[tuple[TrialSpec, Path]] = []

    def submit(self, spec: TrialSpec, work_dir: Path) -> None:
        self.submitted.append(spec.seed)
        self._queue.append((spec, work_dir))

    def poll(self, timeout_s: float) -> list[Finished]:
        out = []
        for spec, work in self._queue[:2]:
            out.append(Finished(spec, self._trial(spec, work), work))
        del self._queue[:2]
        return out

    def _trial(self, spec: TrialSpec, work: Path) -> TrialOutcome:
        folder = work / f"ur10-box-20260101-000000-seed{spec.seed}"
        folder.mkdir(parents=True)
        (work / "trial.log").write_text(f"trial {spec.seed}\n")
        if spec.seed in self.lost:
            (folder / "report.json").write_text('{"scenario": "ur10-box", "stopped": "interru')
            return TrialOutcome(spec.seed, "h", -9, 3.0, folder.name, False, "killed by signal 9")
        rng = np.random.default_rng(spec.seed)
        mm = float(rng.uniform(0.5, 15.0))
        deg = float(rng.uniform(0.0, 3.0))
        stopped = spec.seed % 7 == 3
        criteria = {
            "object_position_error_m": mm * 1e-3,
            "object_angle_error_deg": deg,
            "object_within_tolerance": mm <= 10.0,
            "fsm_done": True,
            "limits": {"position_m": 0.01, "angle_deg": 5.0},
        }
        report = {
            "scenario": "ur10-box",
            "seed": spec.seed,
            "speed": spec.speed,
            "success": mm <= 10.0 and not stopped,
            "perturbation": {"seed": spec.seed, "displacement_mm_deg": [mm, 0.0, deg]},
        }
        if stopped:
            report["stopped"] = f"waiting for the end check of step {spec.seed}: timed out"
        else:
            report["criteria"] = criteria
            report["supervisor"] = {"reason": ""}
        write_json(folder / "report.json", report)
        (folder / "report.md").write_text("# trial\n")
        return TrialOutcome(
            spec.seed, "h", int(not report["success"]), 10.0 + spec.seed, folder.name, True, ""
        )

    def running(self) -> dict[int, Running]:
        return {s.seed: Running("h", 0.0) for s, _ in self._queue[:2]}

    def close(self, interrupted: bool) -> None:
        pass


def settings(trials: int, **kw) -> CampaignSettings:
    return CampaignSettings("ur10-box", 100, trials, speed=0.0, **kw)


def test_a_campaign_reports_what_its_trials_reported(tmp_path, campaign_checks):
    engine = ScriptedEngine(lost={104})
    report = Campaign(tmp_path, settings(12), UR10_BOX, log=lambda m: None).run(engine)
    assert sorted(engine.submitted) == list(range(100, 112))
    campaign_checks(tmp_path, expect_trials=12)
    assert report["counts"]["lost"] == 1 and report["counts"]["pending"] == 0
    assert not (tmp_path / "trials" / "seed104").exists()
    assert (tmp_path / "attempts" / "seed104-1" / "trial.log").exists(), "a lost trial's files"
    assert (
        json.loads((tmp_path / "trials" / "seed100" / "trial.json").read_text())["wall_s"] == 110.0
    )
    # failures grouped: stopped trials (numbers masked), object errors, the lost one
    groups = {g["reason"]: g["seeds"] for g in report["failure_groups"]}
    stopped = [s for s in range(100, 112) if s % 7 == 3]
    assert groups["stopped: waiting for the end check of step #: timed out"] == stopped
    assert groups["lost: killed by signal #"] == [104]
    # the draw of each trial, its speed; the worst trials name the largest errors
    rows = {t["seed"]: t for t in report["trials"]}
    assert rows[101]["draw"]["perturbation"]["seed"] == 101 and rows[101]["speed"] == 0.0
    worst = {w["why"]: w for w in report["worst"]}
    mm = report["criteria"]["object_position_error_m"]
    assert worst["largest object_position_error_m"]["value"] == mm["max"]
    assert mm["unit"] == "mm" and report["criteria"]["object_angle_error_deg"]["unit"] == "deg"
    assert report["slowest"][0] == 111
    md = (tmp_path / "report.md").read_text()
    assert "[104]" not in md and "[101](trials/seed101/report.md)" in md
    assert "controller speed 0 (unpaced" in md
    assert {"criteria.png", "trials.png"} <= set(report["plots"])
    progress = json.loads((tmp_path / "progress.json").read_text())
    assert progress["done"] == 12 and progress["running"] == []


@pytest.mark.slow
def test_a_resumed_campaign_runs_only_what_has_no_report(tmp_path, campaign_checks):
    Campaign(tmp_path, settings(6), UR10_BOX, log=lambda m: None).run(ScriptedEngine(lost={102}))
    kept = (tmp_path / "trials" / "seed100" / "report.json").stat().st_mtime_ns
    engine = ScriptedEngine()
    report = Campaign(tmp_path, settings(8), UR10_BOX, log=lambda m: None).run(engine)
    assert sorted(engine.submitted) == [102, 106, 107], "the lost trial and the new seeds"
    assert (tmp_path / "trials" / "seed100" / "report.json").stat().st_mtime_ns == kept
    assert report["counts"]["lost"] == 0
    campaign_checks(tmp_path, expect_trials=8)
    # fewer trials asked: the campaign keeps its 8
    engine = ScriptedEngine()
    report = Campaign(tmp_path, settings(3), UR10_BOX, log=lambda m: None).run(engine)
    assert engine.submitted == [] and len(report["trials"]) == 8


def test_a_campaign_folder_of_other_settings_is_refused(tmp_path):
    Campaign(tmp_path, settings(2), UR10_BOX, log=lambda m: None).run(ScriptedEngine())
    for other in (settings(2, perturb="all"), settings(2, plan_seed=4)):
        with pytest.raises(CampaignError, match="other settings"):
            Campaign(tmp_path, other, UR10_BOX, log=lambda m: None).prepare()
    (tmp_path / "campaign.json").write_text("{")
    with pytest.raises(CampaignError, match="not a campaign's settings file"):
        Campaign(tmp_path, settings(2), UR10_BOX, log=lambda m: None).prepare()


def test_a_half_written_trial_folder_is_not_finished(tmp_path):
    """Only a complete report counts: a folder left by a crash (no report, a report cut short,
    an interrupted trial's) is run again."""
    c = Campaign(tmp_path, settings(4), UR10_BOX, log=lambda m: None)
    c.prepare()
    for seed, text in (
        (100, None),
        (101, '{"success": tr'),
        (102, '{"success": false, "stopped": "interrupted (Ctrl-C)"}'),
        (103, '{"success": false}'),
    ):
        os.makedirs(c.trial_folder(seed))
        if text is not None:
            (c.trial_folder(seed) / "report.json").write_text(text)
    assert c.prepare() == [100, 101, 102]


def test_units_directions_and_reason_groups():
    assert unit_of("object_position_error_m", 0.1) == ("mm", 1e3)
    assert label("object_position_error_m", "mm") == "object_position_error [mm]"
    assert label("replan_rate_hz.capacity_hz", "Hz") == "replan_rate_hz.capacity [Hz]"
    assert unit_of("replan_solve_ms.median", 2.0) == ("ms", 1.0)
    assert unit_of("replan_rate_hz.capacity_hz", 20.0) == ("Hz", 1.0)
    assert unit_of("zmp_margin_min_m", -0.01) == ("mm", 1e3)
    assert unit_of("holes_visited", 13) == ("count", 1.0)
    assert (
        worse_when("zmp_margin_min_m") == "low" and worse_when("feet_max_displacement_m") == "high"
    )
    assert worse_when("replan_rate_hz.capacity_hz") is None
    assert reason_group("stale for 201 ms (step 3, -1.5e-3)") == "stale for # ms (step #, #)"


def test_the_eta_counts_the_work_the_running_trials_have_done(tmp_path):
    """Mean trial time 100 s, two slots: one trial 40 s in, one queued -> (60 + 100) / 2 s."""
    from marionette.campaigns.campaign import Progress
    from marionette.campaigns.report import TrialRow

    campaign = Campaign(tmp_path, settings(3), UR10_BOX, log=lambda m: None)
    progress = Progress(campaign, to_run=3, t0=0.0, slots=2)
    assert progress.eta_s({}, 3) is None, "no trial finished: no estimate"
    progress.finished(TrialRow(100, "succeeded", run={"wall_s": 100.0}))
    now = time.time()
    running = {101: Running("h", now - 40.0)}
    assert progress.eta_s(running, 1) == pytest.approx(80.0, abs=0.5)
    running = {101: Running("h", now - 140.0)}  # longer than the mean: counted done
    assert progress.eta_s(running, 0) == pytest.approx(0.0, abs=0.5)
