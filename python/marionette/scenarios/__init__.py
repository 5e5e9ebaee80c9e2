"""The experiments of the seed theses, run on the execution runtime (``docs/scenarios.md``).

| module | job |
|---|---|
| `base.py` | `Scenario` (name, robot, scene, criteria, trial), `ScenarioError`, `RunOptions` |
| `harness.py` | the one start-up / run / teardown: LCM URL, logger, controller, perception |
| `report.py` | report pieces every scenario shares (report.json, report.md parts, partial report) |
| `perturbations.py` | seeded perturbations: displacement, slip, push on the held object, offsets |
| `plan_and_execute.py`, `..._report.py` | the plan-then-execute kind and its report |
| `task_error_plot.py` | task errors split by unit (position mm, orientation deg, joints rad) |
| `declarations.py` | plan-and-execute scenarios declared in YAML files, found on a search path |
| `walking_scenario.py` | what the walking scenarios share: moving object, recorder, replans |
| `plank_flip.py`, `ur10_box.py` | plan-and-execute declarations |
| `step_over.py`, `grasp_walk.py` | walking scenarios (thesis 001 ch. 5, 6) |
| `drill.py`, `deburr.py` | tool scenarios (thesis 000 §6.3, §5.3.3) |
| `cli.py` | `marionette demo` |

:data:`SCENARIOS` holds the scenarios declared in this package's modules; :func:`find` also looks
for declaration files (:mod:`.declarations`: the bundled ones, then ``MARIONETTE_SCENARIO_PATH``).
"""

from __future__ import annotations

from pathlib import Path

from marionette.scenarios import deburr, drill, grasp_walk, plank_flip, step_over, ur10_box
from marionette.scenarios.base import Criterion, RunOptions, Scenario, ScenarioError
from marionette.scenarios.declarations import declaration_files, find_declaration

SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        plank_flip.SCENARIO,
        ur10_box.SCENARIO,
        grasp_walk.SCENARIO,
        step_over.SCENARIO,
        drill.SCENARIO,
        deburr.SCENARIO,
    )
}
# `marionette demo` without a scenario (`make demo`): the thesis's experiment, with its arms
# calibrated by the head camera and vision in the loop.
DEFAULT_SCENARIO = "plank-flip"


def names() -> list[str]:
    """Every scenario name :func:`find` knows: the package's and the declaration files' (sorted)."""
    return sorted(set(SCENARIOS) | set(declaration_files()))


def find(name_or_path: str | Path) -> Scenario:
    """The scenario named ``name_or_path`` (the package's, or a declaration file on the search
    path), or the declaration file at that path. ScenarioError naming the close names."""
    return find_declaration(name_or_path, SCENARIOS)


__all__ = [
    "DEFAULT_SCENARIO",
    "SCENARIOS",
    "Criterion",
    "RunOptions",
    "Scenario",
    "ScenarioError",
    "find",
    "names",
]
