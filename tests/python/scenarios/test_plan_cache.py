"""The plan-and-execute scenarios' plan cache: a cached plan is reused only when the problem file
and the model files it was planned from are unchanged (a handle moved in models/objects/ must
replan)."""

from __future__ import annotations

import shutil

import marionette
from marionette.scenarios import SCENARIOS
from marionette.scenarios import plan_and_execute as demo
from marionette.scenarios.plan_and_execute import (
    PLAN_INPUTS_FILE,
    PROBLEMS_DIR,
    cached_plan,
    plan_inputs_digest,
)


def test_the_digest_follows_the_object_models(tmp_path, monkeypatch):
    problem = PROBLEMS_DIR / "ur10_box.yaml"
    models = tmp_path / "models"
    shutil.copytree(marionette.MODELS_DIR / "objects", models / "objects")
    monkeypatch.setattr(marionette, "MODELS_DIR", models)
    before = plan_inputs_digest(problem)
    assert plan_inputs_digest(problem) == before
    handles = models / "objects" / "box.yaml"
    handles.write_text(handles.read_text().replace("0.", "0.0", 1))  # a handle moved
    assert plan_inputs_digest(problem) != before


def test_a_cached_plan_is_reused_only_from_the_same_inputs(tmp_path):
    messages: list[str] = []
    plan = cached_plan(SCENARIOS["ur10-box"], 0, tmp_path, messages.append)
    assert messages[0].startswith("plan: planning")
    again = cached_plan(SCENARIOS["ur10-box"], 0, tmp_path, messages.append)
    assert messages[-1].startswith("plan: cached") and len(again.paths) == len(plan.paths)
    (tmp_path / "ur10_box-seed0" / PLAN_INPUTS_FILE).write_text("planned from other models\n")
    cached_plan(SCENARIOS["ur10-box"], 0, tmp_path, messages.append)
    assert messages[-2].startswith("plan: planning"), messages
    assert (
        demo.plan_inputs_digest(PROBLEMS_DIR / "ur10_box.yaml")
        in (tmp_path / "ur10_box-seed0" / PLAN_INPUTS_FILE).read_text()
    )
