"""The C++ controller and the Python package read the same robot.yaml: for every robot found,
``marionette-controller --describe-robot`` equals what ``marionette.robots`` loads."""

from __future__ import annotations

import json
import os
import subprocess

import pytest

import marionette
from marionette import robots


def describe(build_dir, robot: str, env: dict | None = None) -> dict:
    proc = subprocess.run(
        [build_dir / "marionette-controller", "--describe-robot", "--robot", robot],
        capture_output=True,
        text=True,
        timeout=30,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def python_view(name: str) -> dict:
    d = robots.robot(name)
    sem = robots.semantics(name)
    return {
        "name": d.name,
        "directory": str(d.directory),
        "urdf": str(d.urdf),
        "srdf": str(d.srdf),
        "mjcf": str(d.mjcf),
        "base": d.base,
        "reference": d.reference,
        "contact_bodies": list(d.sole_frames),
        "grip_bodies": [b for g in sem.grippers for b in d.grip_bodies.get(g.name, ())],
        "camera": d.camera or "",
        "camera_frame": d.camera_frame or "",
        "grippers": [
            {
                "name": g.name,
                "joint": g.joint,
                "open_position": g.open_position,
                "closed_position": g.closed_position,
            }
            for g in sem.grippers
            if g.joint is not None
        ],
    }


@pytest.mark.parametrize("name", robots.robot_names())
def test_the_controller_reads_what_python_reads(build_dir, name):
    assert describe(build_dir, name) == python_view(name)


def test_a_robot_folder_on_the_search_path_is_found_by_both(build_dir, tmp_path, monkeypatch):
    import shutil

    folder = tmp_path / "robots" / "copied_arm"
    shutil.copytree(robots.robot("ur10").directory, folder, symlinks=True)
    text = (folder / "robot.yaml").read_text().replace("name: ur10\n", "name: copied_arm\n")
    (folder / "robot.yaml").write_text(text.replace("ur10/", "copied_arm/"))
    monkeypatch.setenv(robots.ROBOT_PATH_VARIABLE, str(tmp_path / "robots"))
    assert "copied_arm" in robots.robot_names()
    env = dict(os.environ, MARIONETTE_BUILD_DIR=str(marionette.BUILD_DIR))
    assert describe(build_dir, "copied_arm", env) == python_view("copied_arm")
    assert describe(build_dir, str(folder), env) == python_view(str(folder))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace("base: fixed", "base: wheeled"), "base 'wheeled' is not one of"),
        (lambda t: t.replace("reference_posture: home\n", ""), "reference_posture is missing"),
        (lambda t: t.replace("name: ur10\n", "name: other\n"), "differs from its folder"),
        (lambda t: t + "  oops: [\n", "not valid YAML"),
    ],
)
def test_a_broken_robot_yaml_is_refused_in_one_line(build_dir, tmp_path, edit, message):
    import shutil

    folder = tmp_path / "ur10"
    shutil.copytree(robots.robot("ur10").directory, folder, symlinks=True)
    (folder / "robot.yaml").write_text(edit((folder / "robot.yaml").read_text()))
    proc = subprocess.run(
        [build_dir / "marionette-controller", "--describe-robot", "--robot", str(folder)],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 1
    assert message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr


def test_an_unknown_robot_lists_the_known_ones(build_dir):
    proc = subprocess.run(
        [build_dir / "marionette-controller", "--describe-robot", "--robot", "nosuch"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert proc.returncode == 1
    assert "unknown robot 'nosuch'; known robots: " in proc.stderr
    assert all(n in proc.stderr for n in robots.robot_names())
