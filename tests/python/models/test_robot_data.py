"""Robots as data: ``marionette robot import`` / ``check`` on arms of example-robot-data that the
project does not ship, and the one-line answers to broken robot folders."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from marionette import robots
from marionette.models.robot_check import check_robot
from marionette.models.robot_import import import_robot
from marionette.schemas import DataFileError

ERD = robots.example_robot_data_dir()


def _errors(findings):
    return [str(f) for f in findings if f.level == "error"]


@pytest.fixture
def on_path(tmp_path, monkeypatch):
    """A robot folder root on $MARIONETTE_ROBOT_PATH."""
    root = tmp_path / "robots"
    root.mkdir()
    monkeypatch.setenv(robots.ROBOT_PATH_VARIABLE, str(root))
    return root


@pytest.mark.parametrize(
    ("urdf", "srdf"),
    [
        ("panda_description/urdf/panda.urdf", "panda_description/srdf/panda.srdf"),
        ("ur_description/urdf/ur5_robot.urdf", "ur_description/srdf/ur5.srdf"),
        ("xarm_description/urdf/xarm7.urdf", "xarm_description/srdf/xarm7.srdf"),
        ("kinova_description/robots/kinova.urdf", "kinova_description/srdf/kinova.srdf"),
    ],
)
def test_an_imported_arm_checks_and_compiles(on_path, build_dir, urdf, srdf):
    name = Path(urdf).stem.replace("_robot", "")
    folder = on_path / name
    notes = import_robot(ERD / urdf, name, folder, ERD / srdf)
    assert notes
    assert not _errors(check_robot(folder)), check_robot(folder)
    assert (folder / f"{name}.xml").is_file()
    # Mimic joints became fixed: Pinocchio's model has exactly the URDF's movable non-mimics.
    root = ET.parse(folder / f"{name}.urdf").getroot()
    movable = [
        j
        for j in root.iter("joint")
        if j.get("type") in ("revolute", "prismatic", "continuous") and j.find("mimic") is None
    ]
    model, _ = robots.load_pinocchio(name, with_collision=False)
    assert model.njoints - 1 == len(movable)
    assert name in robots.robot_names()


def test_a_dae_only_arm_gets_converted_collision_meshes(on_path):
    folder = on_path / "kinova"
    import_robot(ERD / "kinova_description/robots/kinova.urdf", "kinova", folder)
    assert not _errors(check_robot(folder))
    converted = list((folder / "converted_meshes").rglob("*.stl"))
    assert converted, "no DAE converted to STL"
    mjcf = (folder / "kinova.xml").read_text()
    assert "converted_meshes" in mjcf and ".dae" not in mjcf


@pytest.fixture
def ur10_copy(on_path):
    folder = on_path / "ur10"
    shutil.copytree(robots.robot("ur10").directory, folder, symlinks=True)
    return folder


def _edit(folder: Path, old: str, new: str) -> None:
    path = folder / "robot.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("reference_posture: home", "refrence_posture: home", "did you mean 'reference_posture'"),
        ("base: fixed", "base: 3", "3 is not one of"),
        ("link: gripper_link", "link: gripper_lnk", "'gripper_lnk' is not a link"),
        ("joint: finger_joint", "joint: finger_jiont", "'finger_jiont' is not a movable joint"),
        ("closed_position: 0.04", "closed_position: 0.4", "outside finger_joint's limits"),
        ("reference_posture: home", "reference_posture: away", "no group_state 'away'"),
        ("- {joints: finger_", "- {joints: fingerless_", "no entry matches joint 'finger_joint'"),
    ],
)
def test_each_mistake_is_one_finding_naming_what_to_fix(ur10_copy, old, new, expected):
    _edit(ur10_copy, old, new)
    errors = _errors(check_robot(ur10_copy, build=False))
    assert len(errors) == 1 and expected in errors[0], errors
    assert "\n" not in errors[0]


def test_a_yaml_syntax_error_names_the_line(ur10_copy):
    path = ur10_copy / "robot.yaml"
    lines = path.read_text().splitlines()
    lines[10] = lines[10] + ": ]"  # a mapping value where a scalar ends
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFileError, match=r"robot\.yaml:1[01]: not valid YAML"):
        robots.robot(ur10_copy)


def test_a_movable_mimic_joint_is_refused_with_the_fix(on_path):
    folder = on_path / "panda"
    import_robot(
        ERD / "panda_description/urdf/panda.urdf",
        "panda",
        folder,
        ERD / "panda_description/srdf/panda.srdf",
    )
    urdf = folder / "panda.urdf"
    urdf.write_text(
        urdf.read_text().replace(
            '<joint name="panda_finger_joint2" type="fixed">',
            '<joint name="panda_finger_joint2" type="prismatic">',
        )
    )
    (error,) = _errors(check_robot(folder, build=False))
    assert "panda_finger_joint2" in error and 'make it type="fixed"' in error
