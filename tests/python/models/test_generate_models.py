"""scripts/generate_models.py is deterministic and the committed models/ are its output."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

from marionette import MODELS_DIR, REPO_ROOT
from marionette.models import generate


def _is_source(rel: str) -> bool:
    """Files people write (robot folders' robot.yaml, URDF and SRDF that no script derives,
    scene declarations, objects brought as data): everything without a GENERATED mark."""
    path = MODELS_DIR / rel
    return (
        path.suffix in (".md", ".yaml", ".urdf", ".srdf") and b"GENERATED" not in path.read_bytes()
    )


@pytest.fixture(scope="module")
def fresh(tmp_path_factory):
    """A fresh run of the generator (the real script) into an empty directory."""
    out = tmp_path_factory.mktemp("models")
    subprocess.run(
        [sys.executable, str(REPO_ROOT / "scripts" / "generate_models.py"), "--out", str(out)],
        check=True,
        capture_output=True,
        text=True,
    )
    return out


def _files(root):
    """Generated files under ``root``; meshes apart (linked, converted, or the convex pieces
    kept beside a robot, checked against their sources in test_convex_parts.py)."""
    skip = {"meshes", "converted_meshes", "convex_meshes"}
    return {
        p.relative_to(root).as_posix()
        for p in root.rglob("*")
        if p.is_file() and not p.is_symlink() and not skip & set(p.relative_to(root).parts)
    }


@pytest.mark.slow
def test_committed_models_are_byte_identical_to_a_fresh_run(fresh):
    committed = {f for f in _files(MODELS_DIR) if not _is_source(f)}
    generated = _files(fresh) - {
        f for f in _files(fresh) if (MODELS_DIR / f).exists() and _is_source(f)
    }
    assert committed == generated, "stale or missing files: rerun scripts/generate_models.py"
    different = [
        f for f in sorted(generated) if (fresh / f).read_bytes() != (MODELS_DIR / f).read_bytes()
    ]
    assert not different, f"regenerate and commit: {different}"


@pytest.mark.slow
def test_two_runs_give_the_same_bytes(fresh):
    again = generate.generated_files()
    assert {k: v for k, v in again.items()} == {f: (fresh / f).read_bytes() for f in again}


def test_every_mesh_of_every_mjcf_resolves_through_the_mesh_links():
    generate.link_meshes(MODELS_DIR)  # idempotent
    generate.link_meshes(MODELS_DIR)
    n = 0
    for xml in sorted(p for p in MODELS_DIR.glob("*/*.xml") if "GENERATED" in p.read_text()):
        root = ET.parse(xml).getroot()
        meshdir = xml.parent / root.find("compiler").get("meshdir")
        texturedir = xml.parent / root.find("compiler").get("texturedir")
        for mesh in root.iter("mesh"):
            if mesh.get("file"):
                assert (meshdir / mesh.get("file")).is_file(), f"{xml.name}: {mesh.get('file')}"
                n += 1
        for tex in root.iter("texture"):
            if tex.get("file"):
                assert (texturedir / tex.get("file")).is_file(), f"{xml.name}: {tex.get('file')}"
    assert n > 50


def test_link_meshes_refuses_to_replace_a_real_directory(tmp_path):
    import shutil

    (tmp_path / "talos" / "meshes").mkdir(parents=True)
    for f in ("robot.yaml", "talos.urdf", "talos.srdf"):
        shutil.copy(MODELS_DIR / "talos" / f, tmp_path / "talos" / f)
    with pytest.raises(FileExistsError, match="not a symbolic link"):
        generate.link_meshes(tmp_path)


def test_link_meshes_makes_the_converted_meshes_a_fresh_checkout_lacks(tmp_path):
    """converted_meshes/ is not versioned: the set-up's `generate_models.py --link-meshes`
    converts again the DAE meshes each robot's MJCF names."""
    import shutil

    converting = [
        p.parent
        for p in MODELS_DIR.glob("*/*.xml")
        if (p.parent / "robot.yaml").is_file() and "converted_meshes" in p.read_text()
    ]
    if not converting:
        pytest.skip("no bundled robot has DAE-only collision meshes")
    for folder in converting:
        shutil.copytree(folder, tmp_path / folder.name, ignore=shutil.ignore_patterns("*meshes"))
    generate.link_meshes(tmp_path)
    for folder in converting:
        xml = tmp_path / folder.name / f"{folder.name}.xml"
        files = [m.get("file") for m in ET.parse(xml).getroot().iter("mesh") if m.get("file")]
        assert files and all((tmp_path / f).is_file() for f in files), folder.name
