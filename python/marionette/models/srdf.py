"""SRDF a robot needs beside its URDF: the reference posture (``group_state``) and the collision
pairs a planner should skip (``disable_collisions``), computed when a robot has no SRDF of its
own (``marionette robot import``) and for the bundled robots whose URDF the project edits."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping

import numpy as np

from .xml_util import fmt_vec, indent_and_serialize, sub


def disabled_collision_pairs(
    urdf_text: str, samples: int = 300, seed: int = 0
) -> list[tuple[str, str, str]]:
    """Link pairs whose collisions a planner should skip: links on the same rigid body or on
    adjacent moving bodies ("Adjacent"), and pairs in collision in >= 95 % of uniformly
    sampled configurations ("Default": geometric overlap built into the model)."""
    import pinocchio as pin

    from marionette.robots import package_dirs

    model = pin.buildModelFromXML(urdf_text)
    geom = pin.buildGeomFromUrdfString(
        model, urdf_text, pin.GeometryType.COLLISION, None, package_dirs()
    )
    geom.addAllCollisionPairs()
    link_of = [model.frames[g.parentFrame].name for g in geom.geometryObjects]
    joint_of = [g.parentJoint for g in geom.geometryObjects]
    parents = model.parents
    out: dict[tuple[str, str], str] = {}
    for cp in geom.collisionPairs:
        a, b = cp.first, cp.second
        ja, jb = joint_of[a], joint_of[b]
        if ja == jb or parents[ja] == jb or parents[jb] == ja:
            out[tuple(sorted((link_of[a], link_of[b])))] = "Adjacent"
    data, gdata = model.createData(), pin.GeometryData(geom)
    rng = np.random.default_rng(seed)
    counts = np.zeros(len(geom.collisionPairs))
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    lo = np.where(np.isfinite(lo), lo, -np.pi)  # continuous joints: one turn
    hi = np.where(np.isfinite(hi), hi, np.pi)
    for _ in range(samples):
        q = lo + rng.random(model.nq) * (hi - lo)
        pin.computeCollisions(model, data, geom, gdata, q, False)
        counts += [r.isCollision() for r in gdata.collisionResults]
    for k, cp in enumerate(geom.collisionPairs):
        pair = tuple(sorted((link_of[cp.first], link_of[cp.second])))
        if pair[0] != pair[1] and pair not in out and counts[k] >= 0.95 * samples:
            out[pair] = "Default"
    return sorted((a, b, r) for (a, b), r in out.items() if a != b)


def srdf_text(
    robot_name: str,
    state: str,
    posture: Mapping[str, float],
    pairs: list[tuple[str, str, str]],
    comment: str,
    root_joint: str | None = None,
) -> str:
    """An SRDF with one ``group_state`` ``state`` (``posture``: joint -> value; ``root_joint``:
    the planar base's "x y cos sin" values) and the ``disable_collisions`` ``pairs``."""
    root = ET.Element("robot", name=robot_name)
    gs = sub(root, "group_state", name=state, group="all")
    if root_joint is not None:
        sub(gs, "joint", name="root_joint", value=root_joint)
    for joint, value in posture.items():
        sub(gs, "joint", name=joint, value=fmt_vec([value]))
    for a, b, reason in pairs:
        sub(root, "disable_collisions", link1=a, link2=b, reason=reason)
    return indent_and_serialize(root, comment)
