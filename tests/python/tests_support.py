"""Small helpers for tests that drive processes."""

from __future__ import annotations

import contextlib
import json
import select
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

import lcm
from marionette.control.client import ControllerClient
from marionette.processes import ProcessGroup


def wait_for_line(stream: IO[str], needle: str, timeout_s: float) -> str | None:
    """Read ``stream`` line by line until one contains ``needle``; None on timeout or EOF."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([stream], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            return None
        line = stream.readline()
        if not line:
            return None
        if needle in line:
            return line
    return None


@contextlib.contextmanager
def controller_running(
    build_dir: Path,
    lcm_url: str,
    log_dir: Path,
    *args: str,
    camera: bool = False,
    ready_timeout: float = 60.0,
    binary: Path | None = None,
) -> Iterator[ControllerClient]:
    """Starts marionette-controller (``binary``, default the build's) with ``args`` and yields a
    ready ControllerClient; the process is stopped afterwards and must exit cleanly."""
    binary = binary or build_dir / "marionette-controller"
    with (
        ProcessGroup(lcm_url, log_dir) as group,
        ControllerClient(lcm_url, camera=camera) as client,
    ):
        proc = group.start("controller", [binary, "--lcm-url", lcm_url, *args])
        try:
            client.wait_ready(ready_timeout)
        except TimeoutError:
            group.check_alive()
            raise
        client.process = proc
        client.group = group
        yield client
        group.check_alive()
        code = group.stop("controller", timeout_s=10.0)
        assert code == 0, f"controller exited with {code}:\n{proc.log_tail()}"


def demo_process(
    scenario: str, *args: str, out, timeout_s: float, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """``marionette demo SCENARIO ARGS... --out OUT`` in its own Python, through
    :func:`run_stopping_what_it_started`."""
    argv = [sys.executable, "-m", "marionette.cli", "demo", scenario, *args, "--out", str(out)]
    return run_stopping_what_it_started(argv, timeout_s, env)


def run_stopping_what_it_started(
    argv: list[str], timeout_s: float, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """``subprocess.run(argv, capture_output=True, text=True)`` for a command that starts
    processes of its own (a demo: controller, perception, logger, ...). When the test ends it
    early (its timeout, pytest-timeout, Ctrl-C), the command gets SIGTERM, on which it stops
    what it started (tests/python/test_processes.py), then SIGKILL after 30 s. subprocess.run
    SIGKILLs it at once: its children, each in its own session, ran on for the rest of the
    suite (a timed-out deburr demo left its controller and perception at ~90 % of a core for
    40 minutes, and the demos after it failed on timing)."""
    with subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    ) as proc:
        try:
            out, err = proc.communicate(timeout=timeout_s)
        except BaseException:
            proc.terminate()
            try:
                proc.communicate(timeout=30.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
            raise
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


def run_demo(
    name: str,
    out_dir: Path,
    env: dict[str, str],
    speed: float,
    timeout_s: float,
    files: tuple[str, ...] = (),
    args: tuple[str, ...] = (),
) -> tuple[Path, dict[str, Any]]:
    """Runs ``marionette demo <name> --speed <speed> --out <out_dir> <args>`` and checks what a
    user checks first: exit code 0, a single run folder whose report says success, and ``files``
    of that folder not empty; and that the report carries the scenario's declaration, a measure
    of each of its criteria and the scene a replay draws; and that the run's first 10 s replay
    exactly. Returns the run folder and its report.json."""
    proc = demo_process(
        name, "--speed", str(speed), *args, out=out_dir, timeout_s=timeout_s, env=env
    )
    print(proc.stdout)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (run,) = out_dir.glob(f"{name}-*")
    report = json.loads((run / "report.json").read_text())
    assert report["success"], report["summary"]
    for file in files:
        assert (run / file).stat().st_size > 0, file
    from marionette import REPO_ROOT
    from marionette.scenarios import find

    scenario = find(name)
    assert report["declaration"] == json.loads(json.dumps(scenario.declaration()))
    missing = [c.key for c in scenario.criteria() if c.key not in report["criteria"]]
    assert not missing, f"criteria without a measure in report.json: {missing}"
    assert (REPO_ROOT / report["scene"]).is_file() and (
        REPO_ROOT / report["controller_scene"]
    ).is_file()
    # The run replays: from its start-up options (encoder offsets, scene) and the controller's own
    # journal, the first REPLAYED_TICKS give the recorded commands exactly.
    from marionette.control.replay_cli import replay_controller

    replay = replay_controller(run / "run.lcmlog", max_ticks=REPLAYED_TICKS)
    assert replay["ok"] and replay["commands_compared"] > 0, replay
    return run, report


# Ticks of a demo's run replayed by run_demo (10 s of controller time: TALOS replays ~1500 ticks a
# second, and a deburr run is 12 minutes long).
REPLAYED_TICKS = 10_000


def lcm_log_messages(path: Path, types: dict[str, Any]) -> Iterator[tuple[str, Any]]:
    """(channel, decoded message) of every event of an LCM log on one of ``types``' channels
    (channel -> LCM type), in log order."""
    for event in lcm.EventLog(str(path), "r"):
        if event.channel in types:
            yield event.channel, types[event.channel].decode(event.data)


def robot_states_at(path: Path, utimes: set[int]) -> dict[int, Any]:
    """The ROBOT_STATE messages of an LCM log stamped at ``utimes`` (a demo report's verdict
    times), by utime; asserts that every one is there."""
    from marionette import channels, lcmt_robot_state

    states = {
        msg.utime: msg
        for _, msg in lcm_log_messages(path, {channels.ROBOT_STATE: lcmt_robot_state})
        if msg.utime in utimes
    }
    assert set(states) == set(utimes), (
        f"{len(set(utimes) - set(states))} verdict times not in {path}"
    )
    return states
