"""The plan-and-execute scenarios' plan cache: a cached plan is reused only when the problem file,
the model files and the planner's code it was planned from are unchanged; trials sharing the
cache at once plan each key once and never read half a plan."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest

import marionette
from marionette.scenarios import plan_cache
from marionette.scenarios.plan_and_execute import PROBLEMS_DIR
from marionette.scenarios.plan_cache import cached_plan, plan_folder, plan_inputs_digest

UR10_BOX = PROBLEMS_DIR / "ur10_box.yaml"


def test_the_digest_follows_the_object_models(tmp_path, monkeypatch):
    models = tmp_path / "models"
    shutil.copytree(marionette.MODELS_DIR / "objects", models / "objects")
    monkeypatch.setattr(marionette, "MODELS_DIR", models)
    before = plan_inputs_digest(UR10_BOX)
    assert plan_inputs_digest(UR10_BOX) == before
    handles = models / "objects" / "box.yaml"
    handles.write_text(handles.read_text().replace("0.", "0.0", 1))  # a handle moved
    assert plan_inputs_digest(UR10_BOX) != before


def test_the_digest_follows_the_planner_code(tmp_path, monkeypatch):
    """A changed planner (Python or C++) never serves the plans of the old one."""
    before = plan_inputs_digest(UR10_BOX)
    for part in ("python", "cpp"):
        planning = tmp_path / part
        shutil.copytree(plan_cache.PLANNING_DIR, planning / "planning")
        monkeypatch.setattr(plan_cache, "PLANNING_DIR", planning / "planning")
        if part == "cpp":  # the Python sources as they are, one C++ source changed
            repo = tmp_path / "repo"
            for g in plan_cache.CPP_PLANNING_SOURCES:
                for f in marionette.REPO_ROOT.glob(g):
                    target = repo / f.relative_to(marionette.REPO_ROOT)
                    target.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy(f, target)
            monkeypatch.setattr(marionette, "REPO_ROOT", repo)
            plan_cache.planner_version.cache_clear()
            assert plan_inputs_digest(UR10_BOX) == before, "a copy of the same code"
            (repo / "cpp" / "src" / "planning" / "projector.cc").open("a").write("// changed\n")
        else:
            plan_cache.planner_version.cache_clear()
            assert plan_inputs_digest(UR10_BOX) == before, "a copy of the same code"
            (planning / "planning" / "planner.py").open("a").write("# changed\n")
        plan_cache.planner_version.cache_clear()
        assert plan_inputs_digest(UR10_BOX) != before, part
        monkeypatch.undo()
        plan_cache.planner_version.cache_clear()


@pytest.mark.slow
def test_a_cached_plan_is_reused_only_from_the_same_inputs(tmp_path, monkeypatch):
    messages: list[str] = []
    plan = cached_plan(UR10_BOX, 0, tmp_path, messages.append)
    assert messages[0].startswith("plan: planning")
    again = cached_plan(UR10_BOX, 0, tmp_path, messages.append)
    assert messages[-1].startswith("plan: cached") and len(again.paths) == len(plan.paths)
    assert plan_folder(UR10_BOX, 0, tmp_path).name.endswith(plan_inputs_digest(UR10_BOX)[:16])
    # Planned by a checkout since removed (the cache is keyed by contents, not by paths): the
    # plan is read as planned from this checkout's problem file, which the trial reads again.
    saved = plan_folder(UR10_BOX, 0, tmp_path) / "plan.json"
    doc = json.loads(saved.read_text())
    doc["problem"]["source"] = str(tmp_path / "removed-checkout" / UR10_BOX.name)
    saved.write_text(json.dumps(doc))
    moved = cached_plan(UR10_BOX, 0, tmp_path, messages.append)
    assert moved.doc["problem"]["source"] == str(UR10_BOX.resolve())
    monkeypatch.setattr(plan_cache, "planner_version", lambda: "another planner")
    cached_plan(UR10_BOX, 0, tmp_path, messages.append)
    assert messages[-2].startswith("plan: planning"), messages
    assert len([p for p in tmp_path.iterdir() if p.is_dir()]) == 2, "one folder per key"


# Each process waits at the barrier (a file per process, all present = go), then asks the cache
# for the same key; prints what it logged and the plan's path lengths.
RACER = textwrap.dedent(
    """
    import json, sys, time
    from pathlib import Path
    from marionette.scenarios.plan_cache import cached_plan
    problem, cache, barrier, me, n = sys.argv[1:]
    Path(barrier, me).touch()
    while len(list(Path(barrier).iterdir())) < int(n):
        time.sleep(0.01)
    log = []
    plan = cached_plan(Path(problem), 0, Path(cache), log.append)
    print(json.dumps({"log": log, "paths": [float(q.sum()) for _, q in plan.paths]}))
    """
)


@pytest.mark.slow
def test_trials_planning_the_same_key_at_once_plan_it_once(tmp_path):
    """Three processes ask for the same uncached plan at the same moment: one plans, the others
    wait for it and read the same plan; nothing half-written is left in the cache."""
    cache, barrier = tmp_path / "cache", tmp_path / "barrier"
    barrier.mkdir()
    n = 3
    racers = [
        subprocess.Popen(
            [sys.executable, "-c", RACER, str(UR10_BOX), str(cache), str(barrier), str(k), str(n)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=dict(os.environ),
        )
        for k in range(n)
    ]
    results = []
    for p in racers:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
        results.append(json.loads(out.strip().splitlines()[-1]))
    planned = [r for r in results if r["log"][0].startswith("plan: planning")]
    assert len(planned) == 1, [r["log"] for r in results]
    assert all("planned beside" in r["log"][0] for r in results if r not in planned), results
    assert all(r["paths"] == results[0]["paths"] for r in results)
    folders = [p.name for p in cache.iterdir() if p.is_dir()]
    assert folders == [plan_folder(UR10_BOX, 0, cache).name], folders  # no scratch folder left
