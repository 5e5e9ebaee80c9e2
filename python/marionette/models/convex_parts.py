"""Convex pieces of a hand link's concave collision mesh, for MuJoCo.

MuJoCo collides a mesh as its convex hull. A gripper's finger link is often concave (a knuckle
by the palm, a finger that curves round the jaw): its hull fills the gap between the jaws, and an
object closed on is pinched by the hulls deep in the jaw instead of by the fingertips, or pushed
out of it. A hand link's collision mesh that fills less than ``MIN_FILL`` of its hull is
therefore given to MuJoCo as an approximate convex decomposition (CoACD: Wei et al., "Approximate
convex decomposition for 3D meshes with collision-aware concavity and tree search", SIGGRAPH
2022), whose pieces follow the link's surface.

The pieces are computed once and kept beside the robot, ``<robot folder>/convex_meshes/<the
mesh's path under the robot folder>_<k>.stl``, with a manifest (``….json``) that names the
source (relative to the manifest), its SHA-256, the decomposition's parameters and the fill
found. They are versioned, so generating the models needs CoACD only when a mesh or the
parameters change.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

MIN_FILL = 0.8  # a CAD mesh of a convex part fills ~95 % of its hull
# CoACD's concavity threshold (the surface's largest distance to its piece's hull, relative to
# the mesh's size), its cap on the pieces, and its seed (the decomposition is then reproducible).
PARAMETERS = {"threshold": 0.05, "max_convex_hull": 8, "seed": 0}


class ConvexPartsError(RuntimeError):
    """A mesh that cannot be decomposed (no triangles, or CoACD missing when it must run)."""


def hull_fill(mesh) -> float:
    """The fraction of its convex hull's volume a trimesh mesh fills: exact when it is closed,
    from 40-voxel-wide fillings otherwise."""
    hull = mesh.convex_hull
    if hull.volume <= 0:
        return 1.0
    if mesh.is_watertight:
        return float(abs(mesh.volume) / hull.volume)
    pitch = max(mesh.extents) / 40
    return float(mesh.voxelized(pitch).fill().volume / hull.voxelized(pitch).fill().volume)


def convex_parts(source: Path, target_stem: Path) -> list[Path]:
    """The meshes MuJoCo should collide for the collision mesh ``source`` of a hand link:
    ``[source]`` when it fills at least ``MIN_FILL`` of its hull, else its convex pieces
    ``target_stem_<k>.stl``; read from ``target_stem.json`` when it was made from the same
    source with the same parameters, computed (and written) otherwise."""
    manifest = target_stem.with_suffix(".json")
    digest = hashlib.sha256(source.read_bytes()).hexdigest()
    if manifest.is_file():
        recorded = json.loads(manifest.read_text())
        if recorded.get("source_sha256") == digest and recorded.get("coacd") == PARAMETERS:
            parts = [_part(target_stem, k) for k in range(recorded["parts"])]
            if all(p.is_file() for p in parts):
                return parts or [source]
    import trimesh

    mesh = trimesh.load(source, force="mesh")
    if mesh.is_empty:
        raise ConvexPartsError(f"{source}: no triangles to decompose")
    fill = hull_fill(mesh)
    pieces = [] if fill >= MIN_FILL else _decompose(mesh, source)
    target_stem.parent.mkdir(parents=True, exist_ok=True)
    for old in target_stem.parent.glob(f"{target_stem.name}_*.stl"):
        if old.stem.removeprefix(f"{target_stem.name}_").isdigit():  # not another mesh's
            old.unlink()
    parts = []
    for k, piece in enumerate(pieces):
        parts.append(_part(target_stem, k))
        piece.export(parts[-1])
    manifest.write_text(
        json.dumps(
            {
                "source": os.path.relpath(source, manifest.parent),
                "source_sha256": digest,
                "coacd": PARAMETERS,
                "fill": round(fill, 3),
                "parts": len(parts),
            },
            indent=1,
        )
        + "\n"
    )
    return parts or [source]


def _part(target_stem: Path, k: int) -> Path:
    return target_stem.with_name(f"{target_stem.name}_{k}.stl")


def _decompose(mesh, source: Path) -> list:
    try:
        import coacd
    except ImportError as e:  # the set-up installs it (scripts/requirements.txt)
        raise ConvexPartsError(
            f"{source} is concave and its convex pieces are not generated yet: they need CoACD "
            "(pip install coacd, as scripts/setup does)"
        ) from e
    import trimesh

    coacd.set_log_level("error")
    pieces = coacd.run_coacd(coacd.Mesh(mesh.vertices, mesh.faces), **PARAMETERS)
    return [trimesh.Trimesh(v, f).convex_hull for v, f in pieces]
