"""Campaigns of the real ur10-box scenario, unpaced: two trials at once on this machine (then
resumed), and on a Ray cluster of two workers started here whose worker running a trial is
killed. Every trial's report arrives, the campaign report agrees with them, and nothing the
campaign started is left running."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from marionette.campaigns.local_cluster import local_cluster, processes_with_env
from tests_support import run_stopping_what_it_started

pytestmark = pytest.mark.slow
TRIAL = ["ur10-box", "--speed", "0", "--plan-seed", "0"]


def demo(args: list[str], env: dict[str, str], timeout_s: float) -> subprocess.CompletedProcess:
    return run_stopping_what_it_started(
        [sys.executable, "-m", "marionette.cli", "demo", *args], timeout_s=timeout_s, env=env
    )


def marked_env(tmp_path: Path) -> dict[str, str]:
    """This environment with a TMPDIR of its own: it marks every process the campaign starts."""
    (tmp_path / "tmp").mkdir()
    return {**os.environ, "TMPDIR": str(tmp_path / "tmp")}


def test_two_trials_at_once_on_this_machine_then_resumed(tmp_path, campaign_checks):
    folder, env = tmp_path / "campaign", marked_env(tmp_path)
    run = demo([*TRIAL, "--trials", "3", "--jobs", "2", "--campaign", str(folder)], env, 900)
    assert run.returncode in (0, 1), run.stdout + run.stderr  # 1: a trial failed
    report = campaign_checks(folder, expect_trials=3)
    assert report["counts"]["lost"] == 0, report["failure_groups"]
    runs = [
        json.loads((folder / "trials" / f"seed{s}" / "trial.json").read_text()) for s in (0, 1, 2)
    ]
    assert {
        json.loads((folder / "trials" / f"seed{s}" / "report.json").read_text())["speed"]
        for s in (0, 1, 2)
    } == {0.0}
    spans = sorted((r["started"], r["started"] + r["wall_s"]) for r in runs)
    assert spans[1][0] < spans[0][1], f"no two trials ran at once: {spans}"
    assert "2 jobs" in report["campaign"]["engine"]
    assert processes_with_env("TMPDIR", env["TMPDIR"]) == []

    before = {
        s: (folder / "trials" / f"seed{s}" / "report.json").stat().st_mtime_ns for s in (0, 1, 2)
    }
    run = demo([*TRIAL, "--trials", "4", "--jobs", "2", "--campaign", str(folder)], env, 900)
    assert "3 already finished (resumed), 1 to run" in run.stdout, run.stdout + run.stderr
    after = {
        s: (folder / "trials" / f"seed{s}" / "report.json").stat().st_mtime_ns for s in (0, 1, 2)
    }
    assert after == before, "a finished trial was run again"
    campaign_checks(folder, expect_trials=4)
    assert processes_with_env("TMPDIR", env["TMPDIR"]) == []


def test_a_ray_campaign_survives_a_killed_worker(tmp_path, campaign_checks):
    """Head + 2 one-CPU workers on 127.0.0.1; the Ray worker running the first trial is killed
    (SIGKILL) once its trial runs: Ray runs the trial again (or it is reported lost with Ray's
    reason); every other trial's report arrives."""
    folder = tmp_path / "campaign"
    with local_cluster(workers=2, cpus_per_worker=1, log_dir=tmp_path / "ray") as cluster:
        driver = subprocess.Popen(
            [sys.executable, "-m", "marionette.cli", "demo", *TRIAL, "--trials", "3",
             "--cluster", cluster.address, "--campaign", str(folder)],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        killed = None
        deadline = time.monotonic() + 600
        while killed is None and time.monotonic() < deadline and driver.poll() is None:
            time.sleep(1.0)
            try:
                running = json.loads((folder / "progress.json").read_text())["running"]
            except (OSError, ValueError, KeyError):
                continue
            # 3 s into a trial of ~10 s: under way (controller, planner...), not yet over (at
            # 10 s, trials on Ray since they stop as fast as with --jobs had already returned)
            started = [r for r in running if r["pid"] and time.time() - r["since"] > 3.0]
            if started:  # kill the worker
                killed = started[0]
                os.kill(killed["pid"], signal.SIGKILL)
        out, _ = driver.communicate(timeout=900)
        assert killed is not None, "no trial seen running\n" + out
        assert driver.returncode in (0, 1), out
        report = campaign_checks(folder, expect_trials=3)
        row = next(t for t in report["trials"] if t["seed"] == killed["seed"])
        if row["status"] == "lost":
            assert row["reason"].startswith("Ray: "), row
        else:
            assert row["attempts"] == 2, row
            trial = json.loads(
                (folder / "trials" / f"seed{row['seed']}" / "trial.json").read_text()
            )
            assert trial["attempts"] == 2 and trial["host"]
        assert all(t["status"] != "lost" for t in report["trials"] if t["seed"] != killed["seed"])
        assert "Ray cluster at 127.0.0.1" in report["campaign"]["engine"]
    assert cluster.leftover == [], "processes outlived the cluster's nodes"
