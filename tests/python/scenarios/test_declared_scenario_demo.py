"""A plan-and-execute scenario declared as data only runs end to end: the UR10 box pick-and-place
written as a YAML file outside the repository (its own name, a looser angle tolerance and the
problem copied beside it, given by a relative path), found through ``MARIONETTE_SCENARIO_PATH``
and run by ``marionette demo NAME``. The report is the scenario's (its declaration, its
tolerance), and the box lands within it."""

from __future__ import annotations

import pytest
import yaml

from marionette.scenarios import SCENARIOS
from tests_support import run_demo


@pytest.mark.slow
def test_a_scenario_declared_in_a_file_plans_and_executes(tmp_path, lcm_env, monkeypatch):
    folder = tmp_path / "my-scenarios"
    (folder / "problems").mkdir(parents=True)
    ur10 = SCENARIOS["ur10-box"]
    (folder / "problems" / "box.yaml").write_text(ur10.problem.read_text())
    doc = {
        **ur10.document(),
        "name": "box-from-data",
        "description": "the UR10 box pick-and-place, declared in a file",
        "problem": "problems/box.yaml",
        "tolerances": {"position_m": 0.01, "angle_deg": 4.0, "grip_n": 1.0},
    }
    (folder / "box-from-data.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    monkeypatch.setenv("MARIONETTE_SCENARIO_PATH", str(folder))  # run_demo's checks find it too
    env = {**lcm_env, "MARIONETTE_SCENARIO_PATH": str(folder)}
    run, report = run_demo(
        "box-from-data", tmp_path / "out", env, speed=3, timeout_s=400, files=("report.md",)
    )
    d = report["declaration"]
    assert d["name"] == "box-from-data" and d["settings"]["tolerances"]["angle_deg"] == 4.0
    assert d["settings"]["problem"] == str((folder / "problems" / "box.yaml").resolve())
    assert report["criteria"]["limits"]["angle_deg"] == 4.0
    assert report["criteria"]["object_position_error_m"] < 0.01
    assert report["criteria"]["grip_within_tolerance"]
    assert "## Success criteria" in (run / "report.md").read_text()
