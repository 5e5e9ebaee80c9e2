"""One trial of a campaign: the ``marionette demo`` command that runs it, run as a child process
in a work folder (its report folder and ``trial.log`` land there), and what it left.

A trial is complete when its report folder holds a ``report.json`` with a verdict: a success, a
failure, or a trial stopped by the scenario itself (``stopped``: planning failed, a process
died, a wait timed out), which is a failure of that trial. A trial interrupted (Ctrl-C, its
worker killed) or whose process died without a report is not complete: a campaign runs it
again.

The child process gets SIGTERM from the kernel when the process that started it dies (Linux
``PR_SET_PDEATHSIG``), and the demo then stops its own processes: a killed Ray worker or campaign
leaves no trial running.
"""

from __future__ import annotations

import io
import json
import os
import socket
import subprocess
import sys
import tarfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import marionette

REPORT = "report.json"
LOG = "trial.log"

# Runs argv[2:] with SIGTERM from the kernel when the thread that started it ends; argv[1] is the
# starter's pid (it may have died before the prctl). SIGTERM is made deliverable first: a Ray
# worker, this trial's starter there, ignores it, and an ignored signal survives exec.
_ORPHAN_GUARD = (
    "import ctypes, os, signal, sys\n"
    "signal.signal(signal.SIGTERM, signal.SIG_DFL)\n"
    "signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})\n"
    "ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG\n"
    "if os.getppid() != int(sys.argv[1]): sys.exit(143)\n"
    "os.execv(sys.argv[2], sys.argv[2:])\n"
)


@dataclass(frozen=True)
class TrialSpec:
    """What a trial runs: ``marionette demo SCENARIO --seed SEED ...`` (the demo's options).
    ``seed`` draws the trial's perturbation and plans it unless ``plan_seed`` is given."""

    scenario: str  # a scenario name, or the path of a declaration file
    seed: int
    plan_seed: int | None = None
    perturb: str = "none"
    speed: float = 1.0
    gripper_admittance: bool | None = None
    controller_url: str | None = None
    dry_run: bool = True  # the controllers played on the plan before anything moves
    split_sim: bool = (
        False  # the robot simulated in marionette-sim, driven over the driver protocol
    )

    def command(self, out: Path) -> list[str]:
        """The demo's command line, writing its report folder in ``out``."""
        argv = [sys.executable, "-m", "marionette.cli", "demo", self.scenario]
        argv += ["--seed", str(self.seed), "--trials", "1", "--speed", repr(self.speed)]
        argv += ["--perturb", self.perturb, "--out", str(out)]
        if self.plan_seed is not None:
            argv += ["--plan-seed", str(self.plan_seed)]
        if self.gripper_admittance is not None:
            argv.append(
                "--gripper-admittance" if self.gripper_admittance else "--no-gripper-admittance"
            )
        if self.controller_url is not None:
            argv += ["--controller-url", self.controller_url]
        if not self.dry_run:
            argv.append("--no-dry-run")
        if self.split_sim:
            argv.append("--split-sim")
        return argv

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class TrialOutcome:
    """How a trial's process ended. ``folder``: its report folder's name in the work folder
    (None: it wrote none); ``reason``: why it is not complete ("" when it is)."""

    seed: int
    host: str
    exit_code: int | None
    wall_s: float  # [s] the trial's process, start to exit
    folder: str | None
    complete: bool
    reason: str
    started: float = 0.0  # time.time() of the host when the trial's process started

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def complete_report(folder: Path) -> dict[str, Any] | None:
    """The report of a complete trial (module docstring) in ``folder``, else None."""
    try:
        report = json.loads((folder / REPORT).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(report, dict) or not isinstance(report.get("success"), bool):
        return None
    if str(report.get("stopped", "")).startswith("interrupted"):
        return None
    return report


def child_environment() -> dict[str, str]:
    """This process's environment, with this marionette and its build first."""
    env = dict(os.environ)
    python_dir = str(Path(marionette.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (python_dir, env.get("PYTHONPATH")) if p)
    env["MARIONETTE_BUILD_DIR"] = str(marionette.BUILD_DIR)
    return env


def run_trial(
    spec: TrialSpec,
    work_dir: Path,
    started: Callable[[subprocess.Popen], None] | None = None,
) -> TrialOutcome:
    """Runs the trial's demo with ``work_dir`` as its ``--out`` and its output in
    ``work_dir/trial.log``; ``started(popen)`` is called once it runs (a campaign interrupts it
    through it). Waits for it and says what it left."""
    work_dir.mkdir(parents=True, exist_ok=True)
    argv = spec.command(work_dir)
    if sys.platform == "linux":
        argv = [sys.executable, "-c", _ORPHAN_GUARD, str(os.getpid()), *argv]
    t0, started_at = time.perf_counter(), time.time()
    with open(work_dir / LOG, "w") as log:
        popen = subprocess.Popen(
            argv,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=child_environment(),
            cwd=str(marionette.REPO_ROOT),
            start_new_session=True,  # a terminal's Ctrl-C reaches it through the campaign only
        )
        if started is not None:
            started(popen)
        code = popen.wait()
    wall_s = time.perf_counter() - t0
    folders = sorted(p for p in work_dir.iterdir() if p.is_dir())
    folder = folders[-1] if folders else None
    complete = folder is not None and complete_report(folder) is not None
    reason = "" if complete else _why_incomplete(code, folder, work_dir / LOG)
    return TrialOutcome(
        spec.seed,
        socket.gethostname(),
        code,
        wall_s,
        None if folder is None else folder.name,
        complete,
        reason,
        started_at,
    )


def _why_incomplete(code: int | None, folder: Path | None, log: Path) -> str:
    what = "killed by signal " + str(-code) if code is not None and code < 0 else f"exit {code}"
    if folder is None:
        got = "no report folder"
    elif not (folder / REPORT).exists():
        got = "no report.json"
    else:
        got = "an interrupted or unreadable report.json"
    try:
        tail = [line for line in log.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        tail = []
    return f"the trial's process ended ({what}) with {got}" + (f": {tail[-1]}" if tail else "")


def pack(folder: Path) -> bytes:
    """``folder``'s files as a gzip'd tar (fast compression: logs are most of it)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz", compresslevel=1) as tar:
        for p in sorted(folder.iterdir()):
            tar.add(p, arcname=p.name)
    return buffer.getvalue()


def unpack(data: bytes, folder: Path) -> None:
    """The files of :func:`pack` into ``folder`` (no path leaves it)."""
    folder.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        tar.extractall(folder, filter="data")
