"""What every scenario declares, and the one way a trial of it runs.

A scenario is an experiment of the seed theses run on the execution runtime: a robot in a MuJoCo
scene, the task it does there, the seed of its trials, its success criteria with their limits,
the perturbations it accepts and the report it writes (``docs/scenarios.md`` describes each one).
A kind of scenario (:class:`~marionette.scenarios.plan_and_execute.PlanAndExecute`, the walking
and tool scenarios) subclasses :class:`Scenario` and writes :meth:`Scenario.trial`; a trial is run
through :meth:`Scenario.run`, which creates the report folder, starts the report with the
declaration, turns the runtime's failures into :class:`ScenarioError` and, when the trial fails
or is interrupted (Ctrl-C), writes what it had measured so far
(:func:`.report.write_partial_report`).
"""

from __future__ import annotations

import abc
import dataclasses
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import marionette
from marionette.execution.errors import ExecutionError
from marionette.processes import ProcessError

if TYPE_CHECKING:
    from marionette.scenarios.perturbations import Perturbation


class ScenarioError(RuntimeError):
    """The scenario could not run: a bad declaration or option, planning failed, a process died,
    the controller stopped tracking, a wait timed out."""


@dataclass(frozen=True)
class Criterion:
    """One success criterion: ``key``, the entry of a report's ``criteria`` it is judged on;
    what it measures and its limit, as people read them."""

    key: str
    what: str
    limit: str


@dataclass(frozen=True)
class RunOptions:
    """How one trial runs: the ``marionette demo`` options every scenario takes, and those that
    only some kinds accept (:attr:`Scenario.OPTIONS`)."""

    speed: float = 1.0  # controller pacing: 1 real time, 0 as fast as possible
    controller_url: str | None = None  # drive the controller already running there
    view: bool = False  # serve the browser 3D view of the run
    log: Callable[[str], None] = print
    perturbation: Perturbation | None = None  # --perturb (kinds that accept it)
    gripper_admittance: bool | None = None  # None: the scenario's (kinds that have it)
    cache_dir: Path | None = None  # plans (kinds that plan); None: plan_cache.default_cache_dir()
    # Play the generated controllers on the plan before anything moves and refuse a plan that
    # would fail (kinds that plan: marionette.execution.dry_run); False skips it.
    dry_run: bool = True
    # Simulate the robot in marionette-sim, a driver process the controller drives as it would a
    # robot (docs/driver.md), instead of in the controller's process.
    split_sim: bool = False


def repo_relative(path: Path) -> str:
    """``path`` relative to the repository when inside it (reports stay valid in a moved
    checkout), else absolute: how a report names a file (read back by
    :func:`marionette.viewer.replay.run_scene`)."""
    p = Path(os.path.abspath(path))  # not resolve(): a symlinked model stays where it is named
    try:
        return str(p.relative_to(marionette.REPO_ROOT))
    except ValueError:
        return str(p)


@dataclass(frozen=True, kw_only=True)
class Scenario(abc.ABC):
    """A scenario's declaration. ``scene`` is the MJCF scene the controller simulates (a trial may
    run a perturbed copy of it, named in its report); ``seed`` the default seed of trial 1;
    ``seed_experiment`` the experiment of the theses it reproduces."""

    name: str
    description: str
    robot: str
    scene: Path
    seed: int = 0
    seed_experiment: str = ""

    #: The kind's name in a declaration file and in reports.
    KIND: ClassVar[str]
    #: RunOptions fields this kind uses besides speed, controller_url, view and log.
    OPTIONS: ClassVar[tuple[str, ...]] = ()
    #: The report entries (``a.b``: entry b of entry a) holding what the trial's seed drew: its
    #: perturbation, listed per trial in a campaign's report.
    DRAW_KEYS: ClassVar[tuple[str, ...]] = ("perturbation",)

    @abc.abstractmethod
    def criteria(self) -> tuple[Criterion, ...]:
        """The success criteria with their limits, in the order the report lists them."""

    @abc.abstractmethod
    def trial(
        self, seed: int, out_dir: Path, options: RunOptions, report: dict[str, Any]
    ) -> dict[str, Any]:
        """Runs one trial, fills ``report`` (``success``, ``criteria``, ...), writes the report
        folder ``out_dir`` and returns ``report``."""

    def summary(self, report: dict[str, Any], trial_seed: int) -> str:
        """One line for the terminal: the verdict of trial ``trial_seed`` (its report) and the
        measures it rests on."""
        return report["summary"]

    def failure_reason(self, report: dict[str, Any]) -> str:
        """Why a trial failed, for the trials table (``report`` of a failed trial)."""
        return report["summary"]

    def draw(self, report: dict[str, Any]) -> dict[str, Any]:
        """What the seed of the trial behind ``report`` drew (:attr:`DRAW_KEYS` found in it)."""
        out = {}
        for key in self.DRAW_KEYS:
            value: Any = report
            for part in key.split("."):
                value = value.get(part) if isinstance(value, dict) else None
            if value is not None:
                out[key] = value
        return out

    def declared_settings(self) -> dict[str, Any]:
        """The kind's own settings, JSON-able (the declaration's ``settings``)."""
        return {}

    def declaration(self) -> dict[str, Any]:
        """The declaration as data (JSON-able): what a report needs to be read without the
        registry (``marionette replay``)."""
        return {
            "kind": self.KIND,
            "name": self.name,
            "description": self.description,
            "robot": self.robot,
            "scene": repo_relative(self.scene),
            "seed": self.seed,
            "seed_experiment": self.seed_experiment,
            "criteria": [dataclasses.asdict(c) for c in self.criteria()],
            "settings": self.declared_settings(),
        }

    def check_options(self, options: RunOptions) -> None:
        """ScenarioError for an option this kind does not take (one line, naming it)."""
        if options.speed < 0:
            raise ScenarioError(f"speed must be >= 0, got {options.speed}")
        p = options.perturbation
        if p is not None and p.any and "perturbation" not in self.OPTIONS:
            raise ScenarioError(f"{self.name} has its own perturbations (no --perturb)")
        if options.gripper_admittance is not None and "gripper_admittance" not in self.OPTIONS:
            raise ScenarioError(f"{self.name} has no gripper admittance option")
        if not options.dry_run and "dry_run" not in self.OPTIONS:
            raise ScenarioError(f"{self.name} has no dry run to skip (no --no-dry-run)")

    def run(self, seed: int, out_dir: Path, options: RunOptions | None = None) -> dict[str, Any]:
        """One trial with ``seed``: the report dictionary, also written to ``out_dir``
        (report.json, report.md, plots, run.lcmlog, logs/). ScenarioError when it cannot run;
        then, and on Ctrl-C, ``out_dir`` holds the partial report."""
        from marionette.scenarios.report import write_partial_report

        options = options or RunOptions()
        self.check_options(options)
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        report: dict[str, Any] = {
            "scenario": self.name,
            "description": self.description,
            "seed": seed,
            "robot": self.robot,
            "speed": options.speed,
            "scene": repo_relative(self.scene),
            "declaration": self.declaration(),
        }
        try:
            return self.trial(seed, out_dir, options, report)
        except ScenarioError as e:
            write_partial_report(out_dir, report, str(e))
            raise
        except (ExecutionError, ProcessError, TimeoutError) as e:
            write_partial_report(out_dir, report, str(e))
            raise ScenarioError(str(e)) from e
        except KeyboardInterrupt:
            write_partial_report(out_dir, report, "interrupted (Ctrl-C)")
            raise
