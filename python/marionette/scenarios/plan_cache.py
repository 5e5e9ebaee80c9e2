"""The plans of the plan-and-execute scenarios, planned once per key and shared by every trial.

A key is the problem, the seed and a digest of everything the plan depends on besides them
(:func:`plan_inputs_digest`): the problem file, the model files of its robots and objects, and
the planner's own code (:func:`planner_version`), so that a moved handle or a changed planner
never serves a stale plan. Each key is a folder ``<cache>/<problem>-seed<S>-<digest>/`` holding
what ``marionette plan --out`` writes (``plan.json``, ``graph.png``).

The cache is shared by trials running at once (``marionette demo --jobs``) and by a campaign's
later trials:

* a folder is published whole or not at all: planned into a private temporary folder beside it,
  then renamed (``os.rename`` of a folder is atomic), so a reader never sees half a plan;
* a key is planned once: the planner runs under an exclusive lock on ``<key>.lock``
  (``fcntl.flock``, released by the kernel if the process dies); a trial that finds the lock
  held waits for it and then reads the plan the other one published.

The cache folder is ``$MARIONETTE_PLAN_CACHE`` when set (the tests set a temporary one), else
``reports/plans/cache`` of the checkout.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import yaml

import marionette
from marionette import robots
from marionette.planning.path import Plan, load_plan

CACHE_ENV = "MARIONETTE_PLAN_CACHE"
PLANNING_DIR = Path(__file__).resolve().parents[1] / "planning"
# The C++ planning code (projector, path validation) and its bindings, relative to the checkout.
CPP_PLANNING_SOURCES = (
    "cpp/src/planning/*.cc",
    "cpp/include/marionette/planning/*.h",
    "cpp/bindings/planning_*.cc",
)


class PlanningFailed(RuntimeError):
    """``marionette plan`` failed: its exit code and output."""


def default_cache_dir() -> Path:
    """``$MARIONETTE_PLAN_CACHE``, else ``reports/plans/cache`` of the checkout."""
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else marionette.REPO_ROOT / "reports" / "plans" / "cache"


@cache
def planner_version() -> str:
    """SHA-256 of the planner's code: ``python/marionette/planning/*.py`` and the C++ planning
    sources (:data:`CPP_PLANNING_SOURCES`); without the C++ sources (an installed package), the
    compiled module instead."""
    files = sorted(PLANNING_DIR.glob("*.py"))
    cpp = sorted(p for g in CPP_PLANNING_SOURCES for p in marionette.REPO_ROOT.glob(g))
    if not cpp:
        cpp = sorted((marionette.BUILD_DIR / "python" / "marionette").glob("_core*.so"))
    h = hashlib.sha256()
    for f in [*files, *cpp]:
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def plan_inputs_digest(problem: Path) -> str:
    """SHA-256 of what a plan of ``problem`` depends on besides the seed: the problem file, the
    model files of its robots and objects (URDF, SRDF, robot.yaml, handles YAML) and the
    planner's code (:func:`planner_version`). A handle moved in models/objects/ changes it; a
    cache judged by the problem file's date alone kept planning with the old handle."""
    doc = yaml.safe_load(problem.read_text())
    files = [problem]
    for r in doc.get("robots", []):
        if "robot" in r:
            desc = robots.robot(r["robot"])
            files += [desc.urdf, desc.srdf, desc.semantics]
        files += [Path(r[k]) for k in ("urdf", "srdf") if k in r]
    for o in [*doc.get("objects", []), *doc.get("environment", [])]:
        files += [
            marionette.MODELS_DIR / "objects" / f"{o['object']}{ext}" for ext in (".urdf", ".yaml")
        ]
    h = hashlib.sha256(planner_version().encode())
    for f in files:
        h.update(
            str(f.name).encode() + b"\0" + (f.read_bytes() if f.exists() else b"(missing)") + b"\0"
        )
    return h.hexdigest()


def plan_folder(problem: Path, seed: int, cache_dir: Path) -> Path:
    """The folder of the plan of ``problem`` with ``seed`` from today's inputs (it may not
    exist yet)."""
    return cache_dir / f"{problem.stem}-seed{seed}-{plan_inputs_digest(problem)[:16]}"


def cached_plan(problem: Path, seed: int, cache_dir: Path, log: Callable[[str], None]) -> Plan:
    """The plan of ``problem`` for ``seed``: from ``cache_dir`` if planned before from the same
    inputs (:func:`plan_inputs_digest`), else planned now with ``marionette plan`` (same seed and
    inputs -> same plan) and published there (module docstring). PlanningFailed."""
    problem = Path(problem)
    cache_dir.mkdir(parents=True, exist_ok=True)
    folder = plan_folder(problem, seed, cache_dir)
    if (folder / "plan.json").exists():
        log(f"plan: cached {folder / 'plan.json'}")
        return _load(folder, problem)
    with _locked(folder.with_name(folder.name + ".lock")) as waited_s:
        if (folder / "plan.json").exists():  # planned by another trial while we waited
            log(f"plan: cached {folder / 'plan.json'} (planned beside, waited {waited_s:.1f} s)")
            return _load(folder, problem)
        log(f"plan: planning {problem.stem} with seed {seed} ...")
        t0 = time.perf_counter()
        scratch = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=cache_dir))
        try:
            _plan(problem, seed, scratch)
            os.rename(scratch, folder)  # atomic: readers see the whole folder or none
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
    log(f"plan: planned in {time.perf_counter() - t0:.1f} s -> {folder / 'plan.json'}")
    return _load(folder, problem)


def _load(folder: Path, problem: Path) -> Plan:
    """The plan in ``folder``, read as planned from ``problem``: a cached plan names the problem
    file of the checkout that planned it (the cache is keyed by contents, and may be shared
    between checkouts, or outlive the one that planned), and the trial reads the problem again
    (its graph, its checks) from its own, whose inputs are the same."""
    plan = load_plan(folder / "plan.json")
    plan.doc["problem"]["source"] = str(problem.resolve())
    return plan


def _plan(problem: Path, seed: int, out: Path) -> None:
    cmd = [sys.executable, "-m", "marionette.cli", "plan", str(problem), "--out", str(out)]
    cmd += ["--seed", str(seed), "--quiet"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0 or not (out / "plan.json").exists():
        raise PlanningFailed(
            f"planning failed (exit {proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
        )


@contextmanager
def _locked(path: Path) -> Iterator[float]:
    """An exclusive lock on ``path`` (created if needed) for the block; yields the seconds
    waited for it."""
    t0 = time.perf_counter()
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield time.perf_counter() - t0
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
