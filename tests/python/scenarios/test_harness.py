"""The one run sequence of a trial: a trial that fails or is interrupted leaves a partial report,
the runtime's failures reach the user as ScenarioError, options a kind does not take are refused;
with real processes (marionette-controller, marionette-logger), Ctrl-C in the middle of a trial
stops every process of the group and leaves the partial report beside the recorded log."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any, ClassVar

import pytest

from marionette.execution.errors import ExecutionError
from marionette.scenarios import SCENARIOS, RunOptions, ScenarioError
from marionette.scenarios.base import Criterion, Scenario
from marionette.scenarios.harness import Processes, harness
from marionette.scenarios.perturbations import PRESETS, draw


@dataclasses.dataclass(frozen=True, kw_only=True)
class Scripted(Scenario):
    """A scenario whose trial measures one value and then does ``then`` (raise something, or
    start the real processes and raise inside them)."""

    KIND: ClassVar[str] = "scripted"
    then: Any = None
    with_processes: bool = False

    def criteria(self) -> tuple[Criterion, ...]:
        return (Criterion("done", "the script ran to its end", "true"),)

    def trial(self, seed: int, out_dir: Path, options: RunOptions, report: dict) -> dict:
        report["measured"] = 42.0
        if self.with_processes:
            with harness(out_dir, Processes(self.robot, self.scene), options, report) as run:
                report["pids"] = [p.popen.pid for p in run.group.processes]
                run.client.wait_time(0.2)
                raise self.then
        raise self.then


def _scripted(then, **kw) -> Scripted:
    ur10 = SCENARIOS["ur10-box"]
    return Scripted(
        name="scripted", description="a test", robot=ur10.robot, scene=ur10.scene, then=then, **kw
    )


@pytest.mark.parametrize(
    "error,raised",
    [
        (ScenarioError("planning failed"), ScenarioError),
        (ExecutionError("the controller stopped tracking the tool"), ScenarioError),
        (TimeoutError("timed out waiting for the end of a tool move"), ScenarioError),
        (KeyboardInterrupt(), KeyboardInterrupt),
    ],
)
def test_a_stopped_trial_leaves_a_partial_report(tmp_path, error, raised):
    with pytest.raises(raised):
        _scripted(error).run(7, tmp_path / "run")
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert report["success"] is False and report["measured"] == 42.0 and report["seed"] == 7
    reason = "interrupted (Ctrl-C)" if raised is KeyboardInterrupt else str(error)
    assert report["stopped"] == reason
    assert report["declaration"]["kind"] == "scripted"
    assert reason in (tmp_path / "run" / "report.md").read_text()


def test_options_a_kind_does_not_take_are_refused_before_anything_runs(tmp_path):
    drill = SCENARIOS["drill"]
    with pytest.raises(ScenarioError, match="drill has its own perturbations"):
        drill.run(0, tmp_path / "a", RunOptions(perturbation=draw(PRESETS["all"], 3)))
    with pytest.raises(ScenarioError, match="drill has no gripper admittance option"):
        drill.run(0, tmp_path / "b", RunOptions(gripper_admittance=False))
    with pytest.raises(ScenarioError, match="speed must be >= 0"):
        drill.run(0, tmp_path / "c", RunOptions(speed=-1.0))
    offsets = RunOptions(perturbation=draw(PRESETS["joint-offsets"], 3))
    with pytest.raises(
        ScenarioError, match=r"ur10-box: .* joints its scene does not have \(arm_left_1_joint, "
    ):
        SCENARIOS["ur10-box"].run(0, tmp_path / "d", offsets)
    remote = dataclasses.replace(offsets, controller_url="udpm://239.255.76.67:7667?ttl=0")
    with pytest.raises(ScenarioError, match=r"joint offsets need the demo's own controller"):
        SCENARIOS["plank-flip"].run(0, tmp_path / "e", remote)
    assert not any(tmp_path.iterdir())


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie is gone for good
        return f.read().split()[2] != "Z"


def test_ctrl_c_in_a_running_trial_stops_its_processes_and_keeps_what_was_recorded(
    tmp_path, build_dir
):
    run = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        _scripted(KeyboardInterrupt(), with_processes=True).run(
            0, run, RunOptions(speed=0.0, log=lambda m: None)
        )
    report = json.loads((run / "report.json").read_text())
    assert report["stopped"] == "interrupted (Ctrl-C)" and len(report["pids"]) == 2
    assert not [p for p in report["pids"] if _alive(p)]  # the logger and the controller
    assert report["scene"] == report["controller_scene"] == "models/scenes/ur10_box.xml"
    assert (run / "run.lcmlog").stat().st_size > 0
    assert {"logger.log", "controller.log"} <= {p.name for p in (run / "logs").iterdir()}
