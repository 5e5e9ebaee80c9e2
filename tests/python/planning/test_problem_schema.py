"""Problem files: strict validation (schemas/problem.schema.json through jsonschema), one-line
errors, HPP's SRDF syntax (true/false masks) and package:// URIs through a search path."""

from __future__ import annotations

import copy
import re
import subprocess
import sys

import pinocchio as pin
import pytest
import yaml

import marionette
from marionette.planning.problem import ProblemError, load_problem
from marionette.planning.problem_schema import problem_errors, schema

PROBLEMS = marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems"
BUNDLED = [
    *sorted(PROBLEMS.glob("*.yaml")),
    *sorted((marionette.REPO_ROOT / "bench").glob("*/problem.yaml")),
    *sorted((marionette.REPO_ROOT / "tests" / "data" / "planning").glob("*/problem.yaml")),
]
UR10_BOX = yaml.safe_load((PROBLEMS / "ur10_box.yaml").read_text())


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_bundled_problem_is_valid(path):
    assert problem_errors(yaml.safe_load(path.read_text())) == []


def edited(edit):
    doc = copy.deepcopy(UR10_BOX)
    edit(doc)
    return problem_errors(doc)


@pytest.mark.parametrize(
    "edit, expected",
    [
        (
            lambda d: d.update(planer=d.pop("planner")),
            "unknown key 'planer'; did you mean 'planner'?",
        ),
        (
            lambda d: d["planner"].update(max_iteratons=3),
            "unknown key 'max_iteratons' in planner; did you mean 'max_iterations'?",
        ),
        (
            lambda d: d["graph"].update(error_treshold=1e-3),
            "unknown key 'error_treshold' in graph; did you mean 'error_threshold'?",
        ),
        (
            lambda d: d["robots"][0].update(joint_bound={}),
            "unknown key 'joint_bound' in robots[0]; did you mean 'joint_bounds'?",
        ),
        (
            lambda d: d["graph"]["constraints"].append({"locked_joints": "ur10/elbow_joint"}),
            "unknown key 'locked_joints' in graph.constraints[1]; did you mean 'locked_joint'?",
        ),
        (
            lambda d: d["objects"][0].update(bounds=[0, 1, 0, 1]),
            "objects[0].bounds: [0, 1, 0, 1] is too short",
        ),
        (
            lambda d: d["planner"].update(max_iterations="twenty"),
            "planner.max_iterations: 'twenty' is not of type 'integer'",
        ),
        (
            lambda d: d["graph"].update(error_threshold=0),
            "graph.error_threshold: 0 is less than or equal to the minimum of 0",
        ),
        (
            lambda d: d["init"]["box"].update(xyz=[0.7, 0.2]),
            "init.box.xyz: [0.7, 0.2] is too short",
        ),
        (lambda d: d.pop("robots"), "(top level): 'robots' is a required property"),
    ],
)
def test_a_bad_key_or_value_is_named_by_its_path(edit, expected):
    errors = edited(edit)
    assert errors and errors[0] == expected


def test_the_schema_is_a_valid_json_schema_that_refuses_unknown_keys_everywhere():
    """Every mapping the schema describes with properties refuses the others (additional or
    unevaluated properties false, or typed): a typo can not be ignored silently anywhere."""
    import jsonschema

    s = schema()
    jsonschema.validators.validator_for(s).check_schema(s)

    def walk(node, path):
        if isinstance(node, dict):
            if "properties" in node and node.get("type") != "null":
                closed = (
                    node.get("additionalProperties") is False
                    or isinstance(node.get("additionalProperties"), dict)  # typed, e.g. poses
                    or node.get("unevaluatedProperties") is False
                    or path.endswith("model_common")  # closed by robot / object / environment
                )
                assert closed, path
            for k, v in node.items():
                walk(v, f"{path}/{k}")
        elif isinstance(node, list):
            for i, v in enumerate(node):
                walk(v, f"{path}/{i}")

    walk(s, "#")


def run_plan(*args):
    return subprocess.run(
        [sys.executable, "-m", "marionette.cli", "plan", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.slow
def test_cli_refuses_a_typo_in_one_line(tmp_path):
    doc = copy.deepcopy(UR10_BOX)
    doc["planner"]["max_iteratons"] = 3
    bad = tmp_path / "typo.yaml"
    bad.write_text(yaml.safe_dump(doc))
    r = run_plan(bad, "--out", tmp_path / "out")
    assert r.returncode == 1
    assert "Traceback" not in r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and str(bad) in line and "did you mean 'max_iterations'" in line


def test_yaml_syntax_error_is_one_line_with_file_and_line(tmp_path):
    bad = tmp_path / "broken.yaml"
    bad.write_text("name: x\nrobots:\n  - robot: ur10\n  bad: [1, 2\n")
    with pytest.raises(ProblemError) as e:
        load_problem(bad)
    msg = str(e.value)
    assert "\n" not in msg and f"{bad}:" in msg and "not valid YAML" in msg
    line = int(msg.split(f"{bad}:")[1].split(":")[0])
    assert 3 <= line <= 5
    r = run_plan(bad)
    assert r.returncode == 1 and "Traceback" not in r.stderr and r.stderr.count("\n") == 1


BOX_SRDF = """<?xml version="1.0"?>
<robot name="box">
  <handle name="handle" clearance="0.05">
    <position xyz="0 0 0" wxyz="0 0.7071067811865476 0 -0.7071067811865476"/>
    <link name="base_link"/>
    <mask>{mask}</mask>
  </handle>
  <contact name="bottom">
    <link name="base_link"/>
    <point>-0.025 -0.025 -0.025 -0.025 0.025 -0.025 0.025 0.025 -0.025 0.025 -0.025 -0.025</point>
    <shape>4 0 1 2 3</shape>
  </contact>
</robot>
"""


def ur5_box_with(tmp_path, srdf_text: str, urdf: str | None = None):
    bench = marionette.REPO_ROOT / "bench" / "ur5_box"
    doc = yaml.safe_load((bench / "problem.yaml").read_text())
    (tmp_path / "box.srdf").write_text(srdf_text)
    doc["objects"][0]["srdf"] = str(tmp_path / "box.srdf")
    doc["objects"][0]["urdf"] = urdf or str(bench / "box.urdf")
    doc["environment"][0]["urdf"] = str(bench / "table.urdf")
    doc["environment"][0]["srdf"] = str(bench / "table.srdf")
    f = tmp_path / "problem.yaml"
    f.write_text(yaml.safe_dump(doc))
    return f


@pytest.mark.parametrize(
    "mask, expected",
    [
        ("true true true false true true", (True, True, True, False, True, True)),
        ("True TRUE 1 0 false 1", (True, True, True, False, False, True)),
        ("1 1 1 1 1 1", (True,) * 6),
    ],
)
def test_hpp_srdf_masks_are_read(tmp_path, mask, expected):
    p = load_problem(ur5_box_with(tmp_path, BOX_SRDF.format(mask=mask)))
    assert p.handles["box/handle"].mask == expected


@pytest.mark.parametrize(
    "mask, fragment",
    [("true true yes true true true", "'yes'"), ("1 1 1", "6 entries")],
)
def test_a_bad_srdf_mask_is_one_line(tmp_path, mask, fragment):
    f = ur5_box_with(tmp_path, BOX_SRDF.format(mask=mask))
    with pytest.raises(ProblemError) as e:
        load_problem(f)
    assert fragment in str(e.value) and "handle handle" in str(e.value)
    assert "\n" not in str(e.value)


def _srdf_without_each_required_child():
    """BOX_SRDF with one of its required children (<link>, <position>, <point>) removed, for
    every such child of every tag: (srdf text, parent tag, missing tag)."""
    lines = BOX_SRDF.format(mask="1 1 1 1 1 1").splitlines()
    parent = None
    for i, line in enumerate(lines):
        opening = re.match(r"\s*<(\w+)", line)
        tag = opening.group(1) if opening else ""
        if tag in ("handle", "contact"):
            parent = tag
        elif tag in ("link", "position", "point"):
            yield "\n".join(lines[:i] + lines[i + 1 :]), parent, tag


@pytest.mark.parametrize("srdf, parent, missing", list(_srdf_without_each_required_child()))
def test_an_srdf_tag_missing_a_child_is_one_line(tmp_path, srdf, parent, missing):
    with pytest.raises(ProblemError) as e:
        load_problem(ur5_box_with(tmp_path, srdf))
    assert f"<{parent} name=" in str(e.value) and f"has no <{missing}>" in str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "child, fragment",
    [
        ('<approaching_direction xyz="1 0"/>', "approach axis needs 3 numbers"),
        ('<approaching_direction xyz="1 0 0 0"/>', "approach axis needs 3 numbers"),
    ],
)
def test_a_bad_srdf_approach_is_one_line(tmp_path, child, fragment):
    srdf = BOX_SRDF.format(mask="1 1 1 1 1 1").replace("</handle>", f"  {child}\n  </handle>")
    with pytest.raises(ProblemError) as e:
        load_problem(ur5_box_with(tmp_path, srdf))
    assert fragment in str(e.value) and "handle handle" in str(e.value)
    assert "\n" not in str(e.value)


def test_an_empty_srdf_shape_is_one_line(tmp_path):
    srdf = BOX_SRDF.format(mask="1 1 1 1 1 1").replace("<shape>4 0 1 2 3</shape>", "<shape/>")
    with pytest.raises(ProblemError, match="contact 'bottom' has an empty <shape>") as e:
        load_problem(ur5_box_with(tmp_path, srdf))
    assert "\n" not in str(e.value)


def test_package_uris_resolve_through_ros_package_path(tmp_path, monkeypatch):
    """A package of one's own (a folder with package.xml, or a folder of packages), found
    through ROS_PACKAGE_PATH as ROS finds it."""
    bench = marionette.REPO_ROOT / "bench" / "ur5_box"
    pkg = tmp_path / "pkgs" / "my_objects"
    (pkg / "urdf").mkdir(parents=True)
    (pkg / "package.xml").write_text("<package><name>my_objects</name></package>")
    (pkg / "urdf" / "box.urdf").write_text((bench / "box.urdf").read_text())
    srdf = BOX_SRDF.format(mask="1 1 1 1 1 1")
    for entry in (str(pkg), str(tmp_path / "pkgs")):
        monkeypatch.setenv("ROS_PACKAGE_PATH", entry)
        p = load_problem(ur5_box_with(tmp_path, srdf, "package://my_objects/urdf/box.urdf"))
        assert "box/handle" in p.handles
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "elsewhere"))
    with pytest.raises(ProblemError, match="package 'my_objects' not found"):
        load_problem(ur5_box_with(tmp_path, srdf, "package://my_objects/urdf/box.urdf"))


def _operational_frame_names(p) -> list[str]:
    # a joint may share a gripper's name (so100's jaw joint "gripper"): other frame types
    return [f.name for f in p.model.frames if f.type == pin.FrameType.OP_FRAME]


@pytest.mark.parametrize(
    "path", sorted(PROBLEMS.glob("*.yaml")), ids=lambda p: f"{p.parent.name}/{p.name}"
)
def test_every_gripper_and_handle_is_one_frame(path):
    """A robot's HPP SRDF and its description both declare its grippers (TALOS: another
    clearance and 1 cm further): the description wins, and the model has one frame per name
    (HPP refuses a second frame of the same name; Pinocchio would silently find the first)."""
    p = load_problem(path)
    names = _operational_frame_names(p)
    for name in (*p.grippers, *p.handles):
        assert names.count(name) == 1, name


def test_a_handle_declared_twice_is_refused_in_one_line(tmp_path):
    f = ur5_box_with(tmp_path, BOX_SRDF.format(mask="1 1 1 1 1 1"))
    doc = yaml.safe_load(f.read_text())
    doc["objects"][0]["handles"] = [{"name": "handle", "link": "base_link"}]
    f.write_text(yaml.safe_dump(doc))
    with pytest.raises(ProblemError, match="handle box/handle is declared twice") as e:
        load_problem(f)
    assert "\n" not in str(e.value)
