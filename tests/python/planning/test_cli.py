"""`marionette plan` end to end: plan file and graph picture written, errors reported."""

from __future__ import annotations

import subprocess
import sys

import pytest

import marionette
from marionette.planning.path import load_plan

UR5_BOX = marionette.REPO_ROOT / "bench" / "ur5_box" / "problem.yaml"


def run_cli(*args):
    return subprocess.run(
        [sys.executable, "-m", "marionette.cli", "plan", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.slow
def test_plan_writes_plan_and_graph_picture(tmp_path):
    r = run_cli(UR5_BOX, "--out", tmp_path, "--seed", "3")
    assert r.returncode == 0, r.stderr
    assert "planned in" in r.stdout and "iteration" in r.stderr  # progress display
    plan = load_plan(tmp_path / "plan.json")
    assert plan.doc["problem"]["name"] == "ur5_box"
    assert any(" > " in t for t in plan.transitions) and any(" < " in t for t in plan.transitions)
    assert (tmp_path / "graph.png").read_bytes()[:4] == b"\x89PNG"


def test_plan_reports_a_missing_problem_file(tmp_path):
    r = run_cli(tmp_path / "nope.yaml")
    assert r.returncode == 1
    assert "nope.yaml" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_plan_reports_an_unknown_robot(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nrobots:\n  - robot: nao\n")
    r = run_cli(bad)
    assert r.returncode == 1
    assert "unknown robot 'nao'" in r.stderr and "Traceback" not in r.stderr


BUNDLED = sorted(
    p.stem for p in (marionette.REPO_ROOT / "python/marionette/planning/problems").glob("*.yaml")
)


@pytest.mark.parametrize("name", BUNDLED)
def test_a_misspelt_bundled_problem_gets_one_line_with_its_name(name, capsys):
    """Every bundled problem's name with one letter dropped is answered by one line suggesting
    it, exit 1 (not found: docs/errors.md), before anything is loaded."""
    from marionette.cli import main

    cut = len(name) // 2
    typo = name[:cut] + name[cut + 1 :]
    assert main(["plan", typo]) == 1
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and f"did you mean '{name}'" in lines[0], lines
