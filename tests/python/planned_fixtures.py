"""Plans shared by the execution and scenario tests: UR10 box (seed 0) and TALOS plank flip (seed 4,
plans in seconds), planned once per session with `marionette plan` (the scenarios' plan cache).
A test folder's conftest.py imports the fixtures it uses from here."""

from __future__ import annotations

from pathlib import Path

import pytest

from marionette import robots
from marionette.execution.factory import build_specs, context_from_plan
from marionette.execution.plan_steps import PlanRobotMap, plan_robot, steps_from_plan
from marionette.scenarios import SCENARIOS
from marionette.scenarios.plan_and_execute import cached_plan


class Planned:
    """A plan with its steps, robot map and generated controllers."""

    def __init__(self, plan) -> None:
        self.plan = plan
        self.robot = plan_robot(plan)
        self.model, _ = robots.load_pinocchio(self.robot, with_collision=False)
        self.robot_map = PlanRobotMap(
            plan.doc["problem"]["configuration_layout"], self.model, self.robot
        )
        self.steps = steps_from_plan(plan)
        self.ctx = context_from_plan(plan.doc, self.robot, self.model)
        self.specs = build_specs(self.steps, self.ctx)


@pytest.fixture(scope="session")
def plan_cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("plans")


@pytest.fixture(scope="session")
def ur10_box(plan_cache: Path) -> Planned:
    return Planned(cached_plan(SCENARIOS["ur10-box"], 0, plan_cache, log=lambda m: None))


@pytest.fixture(scope="session")
def talos_plank(plan_cache: Path) -> Planned:
    return Planned(cached_plan(SCENARIOS["plank-flip"], 4, plan_cache, log=lambda m: None))
