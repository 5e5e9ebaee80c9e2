"""Fixtures of the planning tests: the UR5 box benchmark problem (bench/ur5_box)."""

from __future__ import annotations

import pytest

import marionette
from marionette.planning.problem import ManipulationProblem, load_problem

UR5_BOX = marionette.REPO_ROOT / "bench" / "ur5_box" / "problem.yaml"


@pytest.fixture(scope="session")
def ur5_box() -> ManipulationProblem:
    return load_problem(UR5_BOX)
