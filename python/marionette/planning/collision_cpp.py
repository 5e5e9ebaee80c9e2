"""The C++ path validator (``marionette._core.planning``) built from a :class:`CollisionChecker`.

:class:`CollisionChecker` keeps the models and the per-transition velocity bounds; this module
only translates them: the kinematic tree (joint kinds, axes, placements), the convex hulls and
primitive shapes, the collision pairs in the same order, and per path the explicit constraints
(locked joint values from the path's right-hand sides, objects attached to a gripper).  The C++
side then runs exactly the certified stepping of ``CollisionChecker._certified`` (same bounds,
same ``CONTACT`` tolerance, same evaluation of the path) without Python per-query overhead.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import coal
import numpy as np
import pinocchio as pin

from marionette._core import planning as _planning

if TYPE_CHECKING:
    from marionette.planning.path import ConstrainedPath
    from marionette.planning.projector import Projector


# Pinocchio short names (without "JointModel") the C++ model builder knows.
_JOINT_KINDS = {
    "RX",
    "RY",
    "RZ",
    "RUBX",
    "RUBY",
    "RUBZ",
    "PX",
    "PY",
    "PZ",
    "RevoluteUnaligned",
    "PrismaticUnaligned",
    "FreeFlyer",
}


def _joint_spec(model: pin.Model, j: int) -> _planning.JointSpec:
    jm = model.joints[j]
    kind = jm.shortname().removeprefix("JointModel")
    if kind not in _JOINT_KINDS:
        raise ValueError(
            f"joint {model.names[j]} ({jm.shortname()}) is not supported by the C++ "
            f"path validator (supported: {', '.join(sorted(_JOINT_KINDS))})"
        )
    axis = (
        np.asarray(jm.extract().axis, dtype=float)
        if kind.endswith("Unaligned")
        else np.array([0.0, 0, 1])
    )
    body = model.inertias[j]
    return _planning.JointSpec(
        model.names[j],
        int(model.parents[j]),
        kind,
        axis,
        model.jointPlacements[j].homogeneous,
        mass=float(body.mass),
        lever=np.asarray(body.lever, dtype=float),
        rotational_inertia=np.asarray(body.inertia, dtype=float),
    )


def _geometry_spec(o: pin.GeometryObject) -> _planning.GeometrySpec:
    g = o.geometry
    args = dict(name=o.name, parent_joint=int(o.parentJoint), placement=o.placement.homogeneous)
    if isinstance(g, coal.Convex):
        tris = np.array(
            [[t[0], t[1], t[2]] for t in (g.polygons(i) for i in range(g.num_polygons))],
            dtype=np.int32,
        )
        return _planning.GeometrySpec(
            kind="convex", points=np.asarray(g.points(), dtype=float), triangles=tris, **args
        )
    if isinstance(g, coal.Box):
        return _planning.GeometrySpec(kind="box", half_side=np.asarray(g.halfSide), **args)
    if isinstance(g, coal.Sphere):
        return _planning.GeometrySpec(kind="sphere", radius=g.radius, **args)
    if isinstance(g, coal.Capsule):
        return _planning.GeometrySpec(
            kind="capsule", radius=g.radius, half_length=g.halfLength, **args
        )
    if isinstance(g, coal.Cylinder):
        return _planning.GeometrySpec(
            kind="cylinder", radius=g.radius, half_length=g.halfLength, **args
        )
    raise ValueError(
        f"geometry {o.name} ({type(g).__name__}) is not supported by the C++ path "
        f"validator (convex hulls, boxes, spheres, capsules, cylinders)"
    )


def build_validator(
    model: pin.Model,
    geom_model: pin.GeometryModel,
    pairs: list[tuple[int, int]],
    contact: float,
    max_queries: int,
) -> _planning.PathValidator:
    """C++ validator over copies of ``model`` (kinematics) and ``geom_model`` (shapes, pairs)."""
    joints = [_joint_spec(model, j) for j in range(1, model.njoints)]
    geoms = [_geometry_spec(o) for o in geom_model.geometryObjects]
    v = _planning.PathValidator(
        joints, geoms, [(int(a), int(b)) for a, b in pairs], contact, max_queries
    )
    if v.nq != model.nq or list(v.idx_qs) != list(model.idx_qs):
        raise ValueError(
            "C++ path validator: configuration layout differs from the Pinocchio model's"
        )
    return v


def attached(projector: Projector) -> tuple[list[int], list[int], list[np.ndarray]]:
    """(idx_q, parent joint, M_PO 4x4) of the objects the projector substitutes from a joint."""
    return (
        [e.idx_q for e in projector.relative],
        [e.parent_joint for e in projector.relative],
        [e.M_PO.homogeneous for e in projector.relative],
    )


def substitution(path: ConstrainedPath, attached_parts: tuple) -> _planning.Substitution:
    """Explicit constraints of ``path``: its locked values (right-hand sides) and attachments."""
    locked = path.projector.locked
    return _planning.Substitution(
        [lk.idx_q for lk in locked], list(path.rhs_state[0]), *attached_parts
    )
