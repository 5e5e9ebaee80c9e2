"""The convex pieces MuJoCo collides for concave hand meshes (models/convex_parts.py), on every
bundled robot: kept pieces match their source, are convex, cover the mesh, and fill about its
volume instead of its hull's."""

from __future__ import annotations

import functools
import hashlib
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from marionette import MODELS_DIR, robots
from marionette.models.convex_parts import MIN_FILL, convex_parts, hull_fill

trimesh = pytest.importorskip("trimesh")
COVER_TOLERANCE = 0.0015  # [m] a point of the mesh's surface lies within this of some piece


def _manifests() -> list[Path]:
    return sorted(MODELS_DIR.glob("*/convex_meshes/**/*.json"))


def _decomposed() -> list[Path]:
    return [m for m in _manifests() if json.loads(m.read_text())["parts"] > 0]


def _pieces(manifest: Path) -> list[Path]:
    n = json.loads(manifest.read_text())["parts"]
    return [manifest.with_name(f"{manifest.stem}_{k}.stl") for k in range(n)]


def _mesh_volume(mesh) -> float:
    if mesh.is_watertight:
        return float(abs(mesh.volume))
    return float(mesh.voxelized(max(mesh.extents) / 60).fill().volume)


def test_the_bundled_concave_hand_meshes_are_decomposed():
    """Every robot's MJCF names the pieces of each decomposition kept beside it, and only
    those; TALOS' concave finger and motor links are among them."""
    assert _decomposed(), "no bundled hand mesh is decomposed"
    for manifest in _manifests():
        folder = manifest.parents[0]
        while folder.name != "convex_meshes":
            folder = folder.parent
        desc = robots.robot(folder.parent)
        named = {
            (MODELS_DIR / m.get("file")).resolve()
            for m in ET.parse(desc.mjcf).getroot().iter("mesh")
            if m.get("file")
        }
        for piece in _pieces(manifest):
            assert piece.resolve() in named, f"{desc.mjcf.name} does not collide {piece}"
    talos = {m.stem for m in _decomposed() if "talos" in m.parts}
    assert {"inner_double_collision", "gripper_motor_single_collision"} <= talos


@pytest.mark.parametrize("manifest", _decomposed(), ids=lambda m: m.stem)
def test_kept_pieces_match_their_source_are_convex_and_cover_it(manifest):
    record = json.loads(manifest.read_text())
    source = (manifest.parent / record["source"]).resolve()
    assert hashlib.sha256(source.read_bytes()).hexdigest() == record["source_sha256"], (
        f"{manifest}: the source mesh changed; rerun scripts/generate_models.py"
    )
    mesh = trimesh.load(source, force="mesh")
    assert record["fill"] == pytest.approx(hull_fill(mesh), abs=0.01)
    assert record["fill"] < MIN_FILL
    pieces = [trimesh.load(p, force="mesh") for p in _pieces(manifest)]
    for p in pieces:
        assert p.is_watertight and p.volume == pytest.approx(p.convex_hull.volume, rel=1e-6)
    # Covered: every point of the mesh's surface is inside a piece, or within the tolerance.
    points = trimesh.sample.sample_surface(mesh, 3000, seed=1)[0]
    outside = np.full(len(points), np.inf)
    for p in pieces:
        hull = p.convex_hull
        planes = hull.face_normals
        distance = (points @ planes.T - np.sum(planes * hull.triangles[:, 0], axis=1)).max(axis=1)
        outside = np.minimum(outside, distance)
    assert outside.max() < COVER_TOLERANCE, f"{outside.max() * 1000:.2f} mm uncovered"
    # Tight: the pieces' volume is near the mesh's, far below its hull's.
    volume = _mesh_volume(mesh)
    total = sum(p.volume for p in pieces)
    assert 0.9 * volume < total < 1.3 * volume < mesh.convex_hull.volume, (total, volume)


def test_a_convex_mesh_stays_whole_and_a_changed_source_is_redone(tmp_path):
    """A box is its own hull: it is collided as itself. A concave mesh (two jaws on a bar) is
    decomposed; when its source changes, the pieces are made again, not reused."""
    box = tmp_path / "box.stl"
    trimesh.creation.box((0.02, 0.03, 0.04)).export(box)
    assert convex_parts(box, tmp_path / "convex" / "box") == [box]
    jaws = tmp_path / "jaws.stl"

    def make(gap: float) -> None:
        bar = trimesh.creation.box((0.08, 0.01, 0.01))
        fingers = [
            trimesh.creation.box((0.01, 0.01, 0.05)).apply_translation((x, 0, 0.03))
            for x in (-0.035 - gap, 0.035 + gap)
        ]
        trimesh.util.concatenate([bar, *fingers]).export(jaws)

    pytest.importorskip("coacd")
    make(0.0)
    first = convex_parts(jaws, tmp_path / "convex" / "jaws")
    assert len(first) >= 3 and first[0] != jaws
    between = np.array([[0.0, 0.0, 0.04]])  # in the gap between the fingers, above the bar
    for p in first:
        hull = trimesh.load(p, force="mesh")
        assert not hull.contains(between)[0]
    before = [p.read_bytes() for p in first]
    assert convex_parts(jaws, tmp_path / "convex" / "jaws") == first  # reused
    assert [p.read_bytes() for p in first] == before
    make(0.01)
    sibling = tmp_path / "convex" / "jaws_tip_0.stl"  # another mesh's piece, kept
    sibling.write_bytes(before[0])
    again = convex_parts(jaws, tmp_path / "convex" / "jaws")
    assert sibling.read_bytes() == before[0]
    record = json.loads((tmp_path / "convex" / "jaws.json").read_text())
    assert record["source_sha256"] == hashlib.sha256(jaws.read_bytes()).hexdigest()
    assert len(again) == record["parts"]


def test_talos_fingertips_alone_close_on_the_plank_at_its_handle():
    """The geometry the pieces fix: TALOS' left gripper at the plank's handle H1 (5.8 cm deep in
    the 43 mm board). Closing, its fingertips reach the board's faces first and, a little past
    that, nothing else of the hand is in the board; with each link collided as its mesh's convex
    hull (MuJoCo's default), the inner links are in the board with the gripper still open."""
    from marionette.models.jaw import Linkage
    from marionette.models.objects import Plank
    from marionette.models.urdf import read_urdf

    desc = robots.robot("talos")
    g = robots.semantics("talos").gripper("talos/left_gripper")
    urdf = read_urdf(desc.urdf)
    linkage = Linkage(urdf, urdf.joints[g.joint], desc.jaws[g.name], g.link, g.pose.matrix())
    plank = Plank()
    X_PH = next(h for h in plank.semantics().handles if h.name == "plank/H1").pose.matrix()
    # Grasped at H1, the gripper frame is the handle's: a point p in it is X_PH p in the board.
    half = np.array(plank.size) / 2

    # Each hand link's collision pieces as the MJCF names them, and its meshes' hulls.
    mjcf = ET.parse(desc.mjcf).getroot()
    files = {m.get("name"): MODELS_DIR / m.get("file") for m in mjcf.iter("mesh") if m.get("file")}
    hand = {b.get("name"): b for b in mjcf.iter("body") if b.get("name") in linkage.link_poses(0)}

    @functools.cache
    def points(link: str, hulls: bool) -> np.ndarray:
        out = []
        for geom in hand[link].findall("geom"):
            mesh = trimesh.load(files[geom.get("mesh")], force="mesh")
            if hulls:
                manifest = files[geom.get("mesh")].with_suffix("")
                stem = manifest.with_name(manifest.name.rsplit("_", 1)[0] + ".json")
                if stem.is_file():  # a piece: collide the whole source mesh's hull instead
                    record = json.loads(stem.read_text())
                    mesh = trimesh.load(stem.parent / record["source"], force="mesh")
                mesh = mesh.convex_hull
            assert "pos" not in geom.attrib and "quat" not in geom.attrib
            out.append(trimesh.sample.sample_surface_even(mesh, 4000, seed=0)[0])
        return np.unique(np.vstack(out), axis=0)

    def inside(link: str, q: float, hulls: bool, depth: float) -> bool:
        X = X_PH @ linkage.link_poses(q)[link]
        p = points(link, hulls) @ X[:3, :3].T + X[:3, 3]
        return bool(np.any(np.all(np.abs(p) < half - depth, axis=1)))

    fingertips = {link for jaw in desc.jaws[g.name] for link in jaw if "fingertip" in link}
    others = set(hand) - fingertips

    def first_touch(links: set[str], hulls: bool) -> float:
        lo, hi = g.open_position, g.closed_position  # open: no contact, closed: in the board
        for _ in range(30):
            mid = (lo + hi) / 2
            lo, hi = (lo, mid) if any(inside(k, mid, hulls, 0.0) for k in links) else (mid, hi)
        return hi

    q_tips = first_touch(fingertips, hulls=False)
    assert g.closed_position < q_tips < g.open_position
    # 0.004 rad further (each jaw ~0.3 mm deeper: 0.08 m/rad), only the fingertips are in it.
    q_past = q_tips + 0.004 * np.sign(g.closed_position - g.open_position)
    assert all(inside(k, q_past, False, 0.0) for k in fingertips)
    assert not [k for k in others if inside(k, q_past, False, 0.0)]
    # With the hulls, the inner links are in the board with the gripper still open.
    assert [k for k in others if inside(k, g.open_position, True, 0.0)]
