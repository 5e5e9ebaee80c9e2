"""The scenario registry and the declarations as data, without processes: every scenario the
package registers is complete and consistent; every plan-and-execute one reads back equal from
its YAML document; the schema refuses bad documents one line per problem, an unknown key with
the known key it was mistyped from; files are found by name on the search path."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import marionette
from marionette import robots
from marionette.scenarios import SCENARIOS, ScenarioError, find, names
from marionette.scenarios.declarations import (
    PATH_VARIABLE,
    declaration_from_document,
    load_declaration,
    schema,
    schema_problems,
)
from marionette.scenarios.plan_and_execute import PlanAndExecute

PLAN_AND_EXECUTE = [s for s in SCENARIOS.values() if isinstance(s, PlanAndExecute)]


def _write(folder: Path, doc: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{doc['name']}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_every_registered_scenario_is_complete(name):
    s = SCENARIOS[name]
    assert s.name == name and s.description and s.seed_experiment
    assert s.scene.is_file(), s.scene
    assert robots.robot(s.robot).urdf.is_file()  # a bundled robot the controller can load
    criteria = s.criteria()
    assert criteria and len({c.key for c in criteria}) == len(criteria)
    assert all(c.what and c.limit for c in criteria)
    d = json.loads(json.dumps(s.declaration()))  # JSON-able: it goes into report.json
    assert d["kind"] == s.KIND and d["name"] == name and d["robot"] == s.robot
    assert (marionette.REPO_ROOT / d["scene"]).resolve() == s.scene.resolve()
    assert [c["key"] for c in d["criteria"]] == [c.key for c in criteria]


def test_the_package_fills_the_registry_without_the_command_line():
    """A library user gets every scenario from ``marionette.scenarios`` alone: nothing of the CLI
    (argument parsers) is imported to fill the registry."""
    code = (
        "import sys, marionette.scenarios as s; "
        "print(sorted(s.SCENARIOS)); "
        "print(sorted(m for m in sys.modules if m.endswith('.cli') or m == 'argparse'))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert out[0] == repr(sorted(SCENARIOS))
    assert "marionette" not in out[1], out[1]
    assert {"deburr", "drill", "grasp-walk", "plank-flip", "step-over", "ur10-box"} <= set(
        SCENARIOS
    )


@pytest.mark.parametrize("scenario", PLAN_AND_EXECUTE, ids=lambda s: s.name)
def test_a_plan_and_execute_declaration_reads_back_equal_from_yaml(tmp_path, scenario):
    doc = scenario.document()
    assert schema_problems(doc) == []
    assert load_declaration(_write(tmp_path, doc)) == scenario
    # the same with every default left out: the file needs only what differs from the kind's
    defaults = PlanAndExecute(
        name=scenario.name,
        description=scenario.description,
        problem=scenario.problem,
        scene=scenario.scene,
        object_name=scenario.object_name,
        max_joint_velocity=scenario.max_joint_velocity,
    ).document()
    lean = {k: v for k, v in doc.items() if k in ("kind", "name") or v != defaults.get(k)}
    lean["tolerances"] = {
        k: v for k, v in doc["tolerances"].items() if v != defaults["tolerances"][k]
    }
    for key in ("description", "problem", "scene", "object", "max_joint_velocity"):
        lean[key] = doc[key]
    assert load_declaration(_write(tmp_path / "lean", lean)) == scenario


def _typo(key: str) -> str:
    """``key`` with two different neighbouring letters swapped (from the middle on)."""
    i = next(i for i in range(max(1, len(key) // 2 - 1), len(key) - 1) if key[i] != key[i + 1])
    return key[:i] + key[i + 1] + key[i] + key[i + 2 :]


def _objects(s: dict, path: tuple[str, ...] = ()):
    """(path, object schema) of every object schema with named properties."""
    if "properties" in s:
        yield path, s
        for k, sub in s["properties"].items():
            yield from _objects(sub, (*path, k))


@pytest.mark.parametrize(
    "where,key",
    [(p, k) for p, s in _objects(schema()) for k in s["properties"]],
    ids=lambda v: "/".join(v) if isinstance(v, tuple) else v,
)
def test_a_mistyped_key_is_refused_with_the_key_it_was_meant_to_be(where, key):
    doc = SCENARIOS["ur10-box"].document()
    doc["vision"] = {"camera_rate_hz": 5.0}
    parent = doc
    for k in where:
        parent = parent.setdefault(k, {})
    typo = _typo(key)
    assert typo != key
    parent[typo] = parent.pop(key, 1)
    problems = schema_problems(doc)
    line = next(p for p in problems if f"unknown key {typo!r}" in p)
    assert line.startswith("/".join(where) or "(top level)"), line
    assert line.endswith(f"did you mean {key!r}?"), line


def test_every_problem_of_a_document_is_named_with_its_place():
    doc = SCENARIOS["plank-flip"].document()
    del doc["object"]
    doc["seed"] = -1
    doc["tolerances"]["angle_deg"] = "5"
    doc["calibrate_arms"] = ["left", "middle"]
    doc["vision"]["frobnicate"] = True
    problems = schema_problems(doc)
    assert len(problems) == 5, problems
    text = "\n".join(problems)
    for expected in (
        "(top level): 'object' is a required property",
        "seed: -1 is less than the minimum of 0",
        "tolerances/angle_deg: '5' is not of type 'number'",
        "calibrate_arms/1: 'middle' is not one of ['left', 'right']",
        "vision: unknown key 'frobnicate'; known keys:",
    ):
        assert expected in text, text
    with pytest.raises(ScenarioError, match=r"x\.yaml: not a valid scenario declaration"):
        declaration_from_document(doc, Path("."), "x.yaml")


def test_bad_references_are_named_with_what_exists(tmp_path):
    doc = SCENARIOS["ur10-box"].document()
    for key, value, message in (
        ("problem", "ur10_boxx", r"no bundled problem 'ur10_boxx'.*did you mean 'ur10_box'\?"),
        ("scene", "ur10_bx", r"no bundled scene 'ur10_bx'.*did you mean 'ur10_box'\?"),
        ("scene", "scenes/missing.xml", r"scene: no file .*scenes/missing\.xml"),
        ("object", "table", r"object 'table' is not a movable object of the problem .*\(box\)"),
        ("robot", "talos", r"robot 'talos' but the problem .* plans for 'ur10'"),
    ):
        bad = {**doc, key: value}
        with pytest.raises(ScenarioError, match=message):
            load_declaration(_write(tmp_path / key / value.replace("/", "_"), bad))
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump(doc))
    with pytest.raises(ScenarioError, match=r"declares the scenario 'ur10-box': name the file"):
        load_declaration(other)
    (tmp_path / "broken.yaml").write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError, match=r"broken\.yaml:\d+: not valid YAML") as e:
        load_declaration(tmp_path / "broken.yaml")
    assert "\n" not in str(e.value)  # one line, as every data file's


def test_paths_in_a_declaration_are_relative_to_its_file(tmp_path):
    s = SCENARIOS["ur10-box"]
    folder = tmp_path / "mine"
    (folder / "data").mkdir(parents=True)
    (folder / "data" / "problem.yaml").write_text(Path(s.problem).read_text())
    doc = {**s.document(), "name": "my-box", "problem": "data/problem.yaml"}
    doc["scene"] = str(s.scene)  # absolute
    mine = load_declaration(_write(folder, doc))
    assert mine.problem == (folder / "data" / "problem.yaml").resolve()
    assert mine == dataclasses.replace(s, name="my-box", problem=mine.problem)


def test_declarations_are_found_by_name_on_the_search_path(tmp_path, monkeypatch):
    base = SCENARIOS["ur10-box"].document()
    first, second = tmp_path / "first", tmp_path / "second"
    _write(first, {**base, "name": "box-a"})
    _write(second, {**base, "name": "box-b"})
    monkeypatch.setenv(PATH_VARIABLE, os.pathsep.join(map(str, (first, second))))
    assert {"box-a", "box-b"} <= set(names()) and set(SCENARIOS) <= set(names())
    assert find("box-b").name == "box-b" and find("ur10-box") is SCENARIOS["ur10-box"]
    assert find(str(first / "box-a.yaml")).name == "box-a"  # a path, found or not
    with pytest.raises(ScenarioError, match=r"no scenario 'box-aa'; did you mean 'box-a'\?"):
        find("box-aa")
    _write(second, {**base, "name": "box-a"})
    with pytest.raises(ScenarioError, match=r"'box-a' is declared 2 times"):
        find("box-a")
    _write(first, {**base})  # a file shadowing a scenario of the package
    with pytest.raises(ScenarioError, match=r"'ur10-box' is declared 2 times: marionette"):
        find("ur10-box")


def test_the_demo_command_names_a_bad_scenario_in_one_line(tmp_path, capsys):
    from marionette.cli import main

    assert main(["demo", "plank-flp"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "did you mean 'plank-flip'?" in err[0], err
    bad = _write(tmp_path, {**SCENARIOS["ur10-box"].document(), "toleranses": {}})
    assert main(["demo", str(bad), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "unknown key 'toleranses'; did you mean 'tolerances'?" in err, err
    assert not (tmp_path / "out").exists()
