"""The C++ Newton-Raphson projector (``_core.planning.Projector``) of a :class:`Projector`.

:class:`Projector` (``projector.py``) compiles its constraints (substitution order, placement +
complement merged into a locked object, free variables, bounds, saturation); this module only
translates that compilation into the C++ specs, once per projector, and each call packs the
current right-hand sides (parametrised constraints, locked values, surface pairs) so that
``set_rhs_from``, ``restore_rhs`` and constraints shared between projectors keep working
unchanged.  The C++ side (``cpp/src/planning/projector.cc``) runs the same Newton loop as
``Projector._project_python``: same steps, schedule, iteration limit, priorities, bounds and
failure reasons.

Constraint kinds the C++ side implements: relative transformation (mask), placement and its
complement, implicit locked joint, centre of mass (the joints' bodies travel in the joint
specs); explicit locked joints and relative poses.  Any other kind keeps the whole projector in
Python (:func:`unsupported` says why).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from marionette._core import planning as _planning
from marionette.planning.collision_cpp import _joint_spec
from marionette.planning.constraints import (
    ComPosition,
    Placement,
    PlacementComplement,
    RelativeTransformation,
    _ImplicitLockedJoint,
)

if TYPE_CHECKING:
    from marionette.planning.projector import Projector


_EMPTY = np.zeros(0)
SUPPORTED = (
    RelativeTransformation,
    Placement,
    PlacementComplement,
    _ImplicitLockedJoint,
    ComPosition,
)


def unsupported(projector: Projector) -> str | None:
    """Why ``projector`` cannot run in C++ (None when it can)."""
    for c in projector.implicit:
        if type(c) not in SUPPORTED:
            return (
                f"constraint {c.name} ({type(c).__name__}) has no C++ implementation "
                f"(supported: {', '.join(t.__name__ for t in SUPPORTED)})"
            )
    model = projector.model
    for j in range(1, model.njoints):
        try:
            _joint_spec(model, j)
        except ValueError as e:
            return str(e)
    return None


class CppProjector:
    """C++ twin of one compiled :class:`Projector` (built by :func:`build`)."""

    def __init__(self, projector: Projector) -> None:
        p = projector
        model = p.model
        self.order = [c for level in p.levels for c in level]  # C++ constraint order
        placements: list[Placement] = []
        for c in self.order:
            plc = c if isinstance(c, Placement) else getattr(c, "placement", None)
            if plc is not None and all(plc is not x for x in placements):
                placements.append(plc)
        self.placements = placements
        index = {id(x): i for i, x in enumerate(placements)}
        selecting = {id(x) for x in p._free_placements}
        implicit = []
        for level, cs in enumerate(p.levels):
            for c in cs:
                if isinstance(c, RelativeTransformation):
                    implicit.append(
                        _planning.ImplicitSpec(
                            "relative",
                            level,
                            joint1=int(c.joint1),
                            M1=c.M1.homogeneous,
                            joint2=int(c.joint2),
                            M2=c.M2.homogeneous,
                            mask=[bool(v) for v in c.mask],
                        )
                    )
                elif isinstance(c, Placement):
                    implicit.append(
                        _planning.ImplicitSpec("placement", level, placement=index[id(c)])
                    )
                elif isinstance(c, ComPosition):
                    implicit.append(
                        _planning.ImplicitSpec(
                            "com",
                            level,
                            joint1=int(c.joint),
                            M1=c.M_JF.homogeneous,
                            mask=[bool(v) for v in c.mask] + [False] * 3,
                        )
                    )
                elif isinstance(c, PlacementComplement):
                    implicit.append(
                        _planning.ImplicitSpec(
                            "complement", level, placement=index[id(c.placement)]
                        )
                    )
                elif isinstance(c, _ImplicitLockedJoint):
                    lk = c.locked
                    implicit.append(
                        _planning.ImplicitSpec(
                            "locked", level, idx_q=int(lk.idx_q), idx_v=int(lk.idx_v), nq=int(lk.nq)
                        )
                    )
                else:  # build() asks unsupported() first
                    raise TypeError(f"constraint {c.name} ({type(c).__name__}) has no C++ twin")
        specs = []
        for plc in placements:
            rels = plc._rel
            specs.append(
                _planning.PlacementSpec(
                    [int(r.joint1) for r in rels],
                    [r.M1.homogeneous for r in rels],
                    [int(r.joint2) for r in rels],
                    [r.M2.homogeneous for r in rels],
                    [np.asarray(poly.a, dtype=float) for poly in plc._polygons],
                    float(plc.margin),
                    id(plc) in selecting,
                )
            )
        self.implicit_locked = [c.locked for c in self.order if isinstance(c, _ImplicitLockedJoint)]
        self.locked = list(p.locked)
        ls = p.line_search
        self.cpp = _planning.Projector(
            [_joint_spec(model, j) for j in range(1, model.njoints)],
            implicit,
            specs,
            [int(lk.idx_q) for lk in p.locked],
            [int(lk.nq) for lk in p.locked],
            [int(e.idx_q) for e in p.relative],
            [int(e.parent_joint) for e in p.relative],
            [int(e.output_joint) for e in p.relative],
            [e.M_PO.homogeneous for e in p.relative],
            bool(p._patchable),
            sorted(int(j) for j in p.kin.static),
            [int(k) for k in p.free_idx],
            [int(k) for k in p._bounded],
            np.asarray(p._lower, dtype=float),
            np.asarray(p._upper, dtype=float),
            [int(k) for k in p._sat_k],
            [int(k) for k in p._sat_q],
            np.asarray(p._sat_lo, dtype=float),
            np.asarray(p._sat_hi, dtype=float),
            ls.kind,
            ls.alpha0,
            ls.alpha_max,
            ls.K,
            ls.alpha_min,
            float(p.max_step),
            p.damping,
        )
        if self.cpp.nq != model.nq:
            raise ValueError("C++ projector: configuration size differs from the Pinocchio model's")

    def rhs(self) -> np.ndarray:
        """Packed right-hand sides, read now (they change with set_rhs_from / restore_rhs)."""
        parts = [c.rhs for c in self.order] + [lk.value for lk in self.locked]
        if self.implicit_locked:
            parts += [lk.value for lk in self.implicit_locked]
        if len(parts) > 1:
            return np.concatenate(parts)
        return parts[0] if parts else _EMPTY

    def pairs(self) -> list[int]:
        return [plc.pair for plc in self.placements]

    def _set_pairs(self, pairs: list[int]) -> None:
        for plc, k in zip(self.placements, pairs):
            plc.pair = k

    def project(
        self, q: np.ndarray, error_threshold: float, max_iterations: int
    ) -> tuple[int, int, float]:
        """(status code, iterations, |e|); q (nq) projected in place, selected pairs written
        back."""
        rhs, pairs = self.rhs(), self.pairs()
        try:
            # In place: pybind11 refuses (TypeError) an array it cannot write without a copy.
            code, it, err, pairs = self.cpp.project(q, rhs, pairs, error_threshold, max_iterations)
        except TypeError:
            if not isinstance(q, np.ndarray) or q.shape != (self.cpp.nq,):
                raise ValueError(
                    f"q must be an array of {self.cpp.nq} entries, got "
                    f"{getattr(q, 'shape', type(q).__name__)}"
                ) from None
            qc = np.ascontiguousarray(q, dtype=np.float64)
            code, it, err, pairs = self.cpp.project(qc, rhs, pairs, error_threshold, max_iterations)
            q[:] = qc
        if self.placements:
            self._set_pairs(pairs)
        return code, it, err

    def is_satisfied(self, q: np.ndarray, threshold: float) -> bool:
        """Projector.is_satisfied (explicit and implicit errors within threshold)."""
        ok, pairs = self.cpp.is_satisfied(q, self.rhs(), self.pairs(), threshold)
        self._set_pairs(pairs)
        return ok


def build(projector: Projector) -> CppProjector | None:
    """The C++ twin of ``projector``, or None when a constraint kind needs Python."""
    if unsupported(projector) is not None:
        return None
    return CppProjector(projector)
