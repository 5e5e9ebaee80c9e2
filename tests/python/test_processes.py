"""ProcessGroup never leaves a process behind, even when the Python process that opened it is
ended by SIGTERM (`timeout`, `kill`, a cancelled CI job): the children run in their own sessions,
so nothing else would stop them (demo trials once left a controller, perceive and lcm-logger
running after the demo was killed)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from marionette.campaigns.local_cluster import processes_with_env
from tests_support import run_stopping_what_it_started

PARENT = """
import sys, time
from marionette.processes import ProcessGroup
with ProcessGroup("udpm://239.255.76.67:7667?ttl=0", sys.argv[1]) as group:
    child = group.start("sleeper", ["sleep", "60"])
    print(child.popen.pid, flush=True)
    time.sleep(60)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its dead parent's reaper) counts as gone
    return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"


@pytest.mark.slow
def test_sigterm_to_the_parent_stops_the_group(tmp_path):
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    try:
        child = int(parent.stdout.readline())
        assert _alive(child)
        parent.send_signal(signal.SIGTERM)
        assert parent.wait(timeout=10) == 128 + signal.SIGTERM
        deadline = time.monotonic() + 5
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(child), "the group's process outlived its parent"
    finally:
        parent.kill()


SLOW_TO_STOP = """
import sys, time
from marionette.processes import ProcessGroup
with ProcessGroup("udpm://239.255.76.67:7667?ttl=0", sys.argv[1]) as group:
    first = group.start("sleeper", ["sleep", "60"])
    last = group.start("stubborn", ["sh", "-c", "trap '' INT; sleep 60"])  # stopped by SIGKILL
    print(first.popen.pid, last.popen.pid, flush=True)
    time.sleep(60)
"""


@pytest.mark.slow
def test_a_second_sigterm_while_the_group_stops_does_not_cut_the_stop_short(tmp_path):
    """A process started with PR_SET_PDEATHSIG gets SIGTERM once per thread of its dying parent:
    the ones that arrive while the group is stopping must not leave the rest running."""
    parent = subprocess.Popen(
        [sys.executable, "-c", SLOW_TO_STOP, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    try:
        children = [int(pid) for pid in parent.stdout.readline().split()]
        time.sleep(0.5)  # the stubborn one's trap is set
        parent.send_signal(signal.SIGTERM)
        time.sleep(1.0)  # the stubborn one ignores SIGINT: the group waits for it
        assert parent.poll() is None, "the group did not wait for its stubborn process"
        parent.send_signal(signal.SIGTERM)
        assert parent.wait(timeout=20) == 128 + signal.SIGTERM
        deadline = time.monotonic() + 5
        while any(map(_alive, children)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not any(map(_alive, children)), "a process outlived its group's parent"
    finally:
        parent.kill()


@pytest.mark.slow
def test_a_demo_a_test_gives_up_on_leaves_no_process(tmp_path, lcm_env):
    """The tests' runner of demos (tests_support.run_stopping_what_it_started) on its timeout: the
    demo is stopped with what it started (controller, perception, logger), nothing runs on into
    the rest of the suite."""
    (tmp_path / "tmp").mkdir()
    env = {**lcm_env, "TMPDIR": str(tmp_path / "tmp")}  # marks every process the demo starts
    argv = [sys.executable, "-m", "marionette.cli", "demo", "ur10-box", "--out", str(tmp_path)]
    seen: list[int] = []  # the most processes of the demo seen at once: it had started them
    done = threading.Event()

    def count() -> None:
        while not done.wait(0.2):
            seen.append(len(processes_with_env("TMPDIR", env["TMPDIR"])))

    watcher = threading.Thread(target=count)
    watcher.start()
    try:
        with pytest.raises(subprocess.TimeoutExpired):
            run_stopping_what_it_started(argv, timeout_s=20.0, env=env)
    finally:
        done.set()
        watcher.join()
    assert max(seen) >= 3, seen  # the demo, its controller and its logger at least
    assert processes_with_env("TMPDIR", env["TMPDIR"]) == []


def test_a_controller_that_exits_at_once_ends_the_wait_at_once_with_its_reason(tmp_path):
    """A controller refusing its arguments (an unknown robot) exits in milliseconds: waiting for
    its first state must stop then, not at the ready timeout (a demo trial spent 60 s there),
    and the error's first line — all a campaign table keeps — must say why."""
    from marionette.control.client import ControllerClient
    from marionette.lcm_bus import private_lcm_url
    from marionette.processes import ProcessError, ProcessGroup

    url = private_lcm_url()
    script = "echo starting; echo \"unknown robot 'arm'\" >&2; exit 1"
    with ProcessGroup(url, tmp_path) as group, ControllerClient(url) as client:
        group.start("controller", ["sh", "-c", script])
        start = time.monotonic()
        with pytest.raises(ProcessError) as error:
            client.wait_ready(30.0, processes=group)
    assert time.monotonic() - start < 10.0
    first = str(error.value).splitlines()[0]
    assert first == "controller exited with code 1: unknown robot 'arm'", first


def _as_a_ray_worker_leaves_it() -> None:
    """The signal state a Ray worker gives the processes it starts (measured: SIGINT blocked,
    SIGTERM ignored), which a non-interactive shell's ``command &`` resembles (SIGINT ignored)."""
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


STOPPABLE_PYTHON = """
import time
from marionette.processes import restore_stop_signals
restore_stop_signals()
print("ready", flush=True)
time.sleep(60)
"""


@pytest.mark.parametrize("program", ["python", "controller", "sim"])
@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_program_started_with_its_stop_signals_blocked_or_ignored_still_stops(
    program, stop, tmp_path
):
    """A group stops its processes with SIGINT and kills them 5 s later: a program that inherited
    a blocked or ignored SIGINT was killed every time, losing its journal (and a trial on a Ray
    worker took twice as long). Each marionette program restores its stop signals first."""
    import marionette

    argv = {
        "python": [sys.executable, "-c", STOPPABLE_PYTHON],
        "controller": [
            str(marionette.BUILD_DIR / "marionette-controller"),
            "--robot",
            "ur10",
            "--backend",
            "kinematic",
            "--camera-rate",
            "0",
        ],
        "sim": [str(marionette.BUILD_DIR / "marionette-sim"), "--robot", "ur10"],
    }[program]
    env = {**os.environ, "MARIONETTE_LCM_URL": "udpm://239.255.76.67:7991?ttl=0"}
    child = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        preexec_fn=_as_a_ray_worker_leaves_it,
    )
    try:
        if program == "python":
            assert child.stdout.readline().strip() == "ready"
        else:
            time.sleep(1.0)  # a signal before its handler is installed ends it too
        child.send_signal(stop)
        try:
            code = child.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{program} did not stop on {signal.Signals(stop).name}")
        # its handler's clean exit, its default action, or KeyboardInterrupt's exit 1
        assert code in (0, 1, -stop), (code, child.stdout.read()[-2000:])
    finally:
        child.kill()
        child.wait()
