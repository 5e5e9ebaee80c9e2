"""Plan-and-execute scenarios declared as data: one YAML file per scenario, ``<name>.yaml``,
validated against ``schemas/scenario.schema.json`` (unknown keys refused with
the closest known one), then read into a :class:`~.plan_and_execute.PlanAndExecute`.

A file is found by its scenario's name on the search path — this package's ``declarations/``
folder, then each folder of ``MARIONETTE_SCENARIO_PATH`` (``os.pathsep``-separated) — or given
by its path (``marionette demo path/to/my-arm-box.yaml``). Example (every key but the first seven
optional; ``docs/scenarios.md``):

.. code-block:: yaml

    kind: plan-and-execute
    name: ur10-box
    description: UR10 picks the box and places it 0.5 m away
    problem: ur10_box          # planning/problems/ur10_box.yaml, or a path relative to this file
    scene: ur10_box            # models/scenes/ur10_box.xml, or a path relative to this file
    object: box                # judged: its final pose vs the plan's goal
    max_joint_velocity: 1.0    # [rad/s]
    seed: 0
    tolerances: {position_m: 0.01, angle_deg: 5.0, grip_n: 1.0}
    gripper_admittance: true
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from marionette import schemas
from marionette.scenarios.base import Scenario, ScenarioError
from marionette.scenarios.plan_and_execute import PROBLEMS_DIR, SCENES_DIR, PlanAndExecute
from marionette.schemas import DataFileError, read_yaml

BUNDLED_DIR = Path(__file__).resolve().parent / "declarations"
PATH_VARIABLE = "MARIONETTE_SCENARIO_PATH"
SUFFIXES = (".yaml", ".yml")


def schema() -> dict[str, Any]:
    return schemas.schema("scenario")


def search_path() -> list[Path]:
    """The folders declaration files are looked for in, in order."""
    extra = [Path(p) for p in os.environ.get(PATH_VARIABLE, "").split(os.pathsep) if p]
    return [BUNDLED_DIR, *extra]


def declaration_files() -> dict[str, list[Path]]:
    """Scenario name (the file's stem) -> the declaration files of that name on the search path."""
    out: dict[str, list[Path]] = {}
    for folder in search_path():
        if folder.is_dir():
            for f in sorted(folder.iterdir()):
                if f.suffix in SUFFIXES and f.is_file():
                    out.setdefault(f.stem, []).append(f)
    return out


def schema_problems(doc: Any) -> list[str]:
    """What is wrong with a declaration document, one line each: where, what, and for an unknown
    key the closest known one."""
    return schemas.problems(doc, "scenario")


def _file(value: str, bundled_dir: Path, suffix: str, base_dir: Path, key: str) -> Path:
    """A bundled file by name (no folder, no suffix) or a path relative to ``base_dir``."""
    if "/" not in value and os.sep not in value and not value.endswith(suffix):
        path = bundled_dir / f"{value}{suffix}"
        if not path.is_file():
            names = sorted(p.stem for p in bundled_dir.glob(f"*{suffix}"))
            close = difflib.get_close_matches(value, names, n=1)
            raise ScenarioError(
                f"{key}: no bundled {key} {value!r} in {bundled_dir}"
                + (f"; did you mean {close[0]!r}?" if close else f" ({', '.join(names)})")
                + f" (or give a path to a {suffix} file)"
            )
        return path
    path = Path(value) if Path(value).is_absolute() else base_dir / value
    if not path.is_file():
        raise ScenarioError(f"{key}: no file {path}")
    return path.resolve()


def declaration_from_document(doc: Any, base_dir: Path, source: str) -> PlanAndExecute:
    """The scenario a declaration document describes; paths in it relative to ``base_dir``.
    ScenarioError naming every problem (``source``: where the document comes from)."""
    problems = schema_problems(doc)
    if problems:
        raise ScenarioError(
            f"{source}: not a valid scenario declaration:\n  " + "\n  ".join(problems)
        )
    tolerances = doc.get("tolerances", {})
    vision = doc.get("vision")
    kwargs: dict[str, Any] = {
        "position_tolerance": tolerances.get("position_m"),
        "angle_tolerance_deg": tolerances.get("angle_deg"),
        "feet_tolerance": tolerances.get("feet_m"),
        "fall_margin": tolerances.get("fall_m"),
        "grip_tolerance": tolerances.get("grip_n"),
        "seed": doc.get("seed"),
        "seed_experiment": doc.get("seed_experiment"),
        "robot": doc.get("robot"),
        "feet": tuple(doc["feet"]) if "feet" in doc else None,
        "gripper_admittance": doc.get("gripper_admittance"),
        "friction_grasps": doc.get("friction_grasps"),
        "calibrate_arms": tuple(doc["calibrate_arms"]) if "calibrate_arms" in doc else None,
        "vision": vision is not None,
    }
    if vision is not None:
        kwargs.update(
            camera_rate=vision.get("camera_rate_hz"),
            servo_slowdown=vision.get("servo_slowdown"),
            quad_decimate=vision.get("quad_decimate"),
            servo_dwell_s=vision.get("servo_dwell_s"),
        )
    try:
        return PlanAndExecute(
            name=doc["name"],
            description=doc["description"],
            problem=_file(doc["problem"], PROBLEMS_DIR, ".yaml", base_dir, "problem"),
            scene=_file(doc["scene"], SCENES_DIR, ".xml", base_dir, "scene"),
            object_name=doc["object"],
            max_joint_velocity=float(doc["max_joint_velocity"]),
            **{k: v for k, v in kwargs.items() if v is not None},  # absent: the kind's default
        )
    except ScenarioError as e:
        raise ScenarioError(f"{source}: {e}") from e


def load_declaration(path: Path) -> PlanAndExecute:
    """The scenario declared in the YAML file ``path`` (named after it: ``<name>.yaml``)."""
    path = Path(path)
    try:
        doc = read_yaml(path)
    except DataFileError as e:
        raise ScenarioError(str(e)) from None
    scenario = declaration_from_document(doc, path.resolve().parent, str(path))
    if scenario.name != path.stem:
        raise ScenarioError(
            f"{path}: declares the scenario {scenario.name!r}: name the file {scenario.name}.yaml"
        )
    return scenario


def find_declaration(name_or_path: str | Path, registry: Mapping[str, Scenario]) -> Scenario:
    """The scenario of ``registry`` or of a declaration file on the search path named
    ``name_or_path``, or the declaration file at that path. ScenarioError when there is none
    (with the closest names) or when two declarations share the name."""
    text = str(name_or_path)
    if text.endswith(SUFFIXES) or "/" in text or os.sep in text:
        return load_declaration(Path(text))
    files = declaration_files()
    found = ["marionette.scenarios"] if text in registry else []
    found += [str(f) for f in files.get(text, [])]
    if len(found) > 1:
        raise ScenarioError(
            f"scenario {text!r} is declared {len(found)} times: {'; '.join(found)} "
            f"(rename all but one)"
        )
    if text in registry:
        return registry[text]
    if text in files:
        return load_declaration(files[text][0])
    known = sorted(set(registry) | set(files))
    close = difflib.get_close_matches(text, known, n=1)
    raise ScenarioError(
        f"no scenario {text!r}"
        + (f"; did you mean {close[0]!r}?" if close else "")
        + f" (scenarios: {', '.join(known)}; declaration files are looked for in "
        + f"{', '.join(map(str, search_path()))} — {PATH_VARIABLE} adds folders)"
    )
