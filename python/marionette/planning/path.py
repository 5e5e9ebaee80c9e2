"""Paths in a transition: constrained straight interpolation, path vectors, plan file I/O.

A :class:`ConstrainedPath` joins two configurations of one transition leaf.  Its free
variables are interpolated on the configuration manifold (``pinocchio.interpolate``) and the
explicit constraints are substituted at every parameter, so a grasped object follows the
gripper exactly and a placed object stays where it is (HPP's straight steering method + path
projection).  When the transition also has implicit constraints (a humanoid's feet and centre
of mass), the straight line is projected progressively (thesis §2.2.2; HPP "Progressive"
projector): every ``step`` along it is projected, consecutive projections must stay close
(continuity), and the path is the polyline through them.

The plan file (format ``marionette-plan/1``, :func:`save_plan` / :func:`load_plan`): a JSON
document (problem, graph, one entry per elementary path with its transition, end states,
grasps and constraint right-hand sides) plus an ``.npz`` with, per path, the sampled
configurations ``path_<i>`` (k x nq) at parameters ``s_<i>`` (k,) (arc length in the metric
|v|, resample at any rate by interpolating on the manifold) and, in a timed plan (``timed``:
true), their times ``t_<i>`` (k,) [s] under the robots' velocity and acceleration limits.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin

if TYPE_CHECKING:
    from marionette.planning.graph import ConstraintGraph, Edge
    from marionette.planning.projector import Projector

PLAN_FORMAT = "marionette-plan/1"


class PathError(RuntimeError):
    """A path that cannot be built (projection failed or discontinuous)."""


class ConstrainedPath:
    """Path in one transition: waypoints (k x nq) of a constrained polyline, parameter s in
    [0, length] (arc length of the free-variable interpolation, |v| metric).

    For purely explicit transitions the polyline has 2 points and every evaluation substitutes
    the explicit constraints; with implicit constraints the points are projections every
    ``step`` (already satisfying the constraints).
    """

    def __init__(
        self, edge: Edge, points: np.ndarray, projector: Projector, rhs: dict[str, list[float]]
    ) -> None:
        self.edge = edge
        self.points = points
        self.projector = projector
        self.rhs = rhs
        self.rhs_state = projector.rhs_state()
        model = projector.model
        self.model = model
        seg = [
            float(np.linalg.norm(pin.difference(model, a, b)[projector.free_idx]))
            for a, b in zip(points, points[1:])
        ]
        self.cum = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.cum[-1])

    @classmethod
    def build(
        cls,
        edge: Edge,
        q1: np.ndarray,
        q2: np.ndarray,
        projector: Projector,
        step: float = 0.05,
    ) -> ConstrainedPath:
        """Path q1 -> q2 under ``projector`` (rhs already set from q1)."""
        model = projector.model
        rhs = projector.rhs_vector()
        if not projector.implicit:
            return cls(edge, np.array([q1, q2]), projector, rhs)
        d = np.linalg.norm(pin.difference(model, q1, q2))
        n = max(1, math.ceil(d / step))
        pts = [q1.copy()]
        for i in range(1, n):
            q = pin.interpolate(model, q1, q2, i / n)
            if not projector.project(q):
                raise PathError(f"{edge.name}: projection failed at {i}/{n}")
            # Continuity (Progressive projector): the projected point may not jump further
            # than twice the interpolation step from the previous one.
            if np.linalg.norm(pin.difference(model, pts[-1], q)) > 2.0 * d / n + 1e-9:
                raise PathError(f"{edge.name}: discontinuous projection at {i}/{n}")
            pts.append(q)
        pts.append(q2.copy())
        return cls(edge, np.array(pts), projector, rhs)

    @property
    def start(self) -> np.ndarray:
        return self.points[0]

    @property
    def end(self) -> np.ndarray:
        return self.points[-1]

    def eval(self, s: float, out: np.ndarray | None = None) -> np.ndarray:
        """Configuration at arc length s (clamped to [0, length]).

        The ends are returned exactly as given (consecutive paths join exactly); in between,
        explicit constraints are substituted, which may differ from the ends by the projection
        threshold."""
        if s <= 0.0 or s >= self.length:
            q = self.points[0 if s <= 0.0 else -1].copy()
            if out is not None:
                out[:] = q
                return out
            return q
        if self.length <= 0.0:
            q = self.points[0].copy()
        elif len(self.points) == 2:
            q = pin.interpolate(
                self.model, self.points[0], self.points[1], min(max(s / self.length, 0.0), 1.0)
            )
        else:
            s = min(max(s, 0.0), self.length)
            i = int(np.searchsorted(self.cum, s, side="right") - 1)
            i = min(i, len(self.points) - 2)
            ds = self.cum[i + 1] - self.cum[i]
            u = 0.0 if ds <= 0 else (s - self.cum[i]) / ds
            q = pin.interpolate(self.model, self.points[i], self.points[i + 1], u)
        self.projector.restore_rhs(self.rhs_state)
        self.projector.apply_explicit(q)
        if out is not None:
            out[:] = q
            return out
        return q

    def extract(self, s0: float, s1: float) -> ConstrainedPath:
        """Sub-path between arc lengths s0 and s1 (s1 < s0 reverses it)."""
        lo, hi = min(s0, s1), max(s0, s1)
        inner = [p for p, c in zip(self.points, self.cum) if lo < c < hi]
        pts = [self.eval(lo)] + inner + [self.eval(hi)]
        if s1 < s0:
            pts = pts[::-1]
        return self._like(np.array(pts))

    def _like(self, points: np.ndarray) -> ConstrainedPath:
        self.projector.restore_rhs(self.rhs_state)
        return ConstrainedPath(self.edge, points, self.projector, self.rhs)

    def reverse(self) -> ConstrainedPath:
        """The same motion backwards, labelled with the reverse transition when there is one
        (a grasp sub-path reversed is the matching release sub-path: same constraints)."""
        rev = getattr(self.edge, "reverse_edge", None)
        if rev is None or rev is self.edge:
            return self._like(self.points[::-1].copy())
        proj = rev.path_projector
        proj.set_rhs_from(self.points[-1])
        return ConstrainedPath(rev, self.points[::-1].copy(), proj, proj.rhs_vector())

    def sample(self, step: float) -> tuple[np.ndarray, np.ndarray]:
        """(s (k,), q (k x nq)) every ``step`` of arc length, both ends included."""
        n = max(1, math.ceil(self.length / step)) if self.length > 0 else 1
        s = np.linspace(0.0, self.length, n + 1)
        return s, np.array([self.eval(x) for x in s])


def concatenate_length(paths: Sequence[ConstrainedPath]) -> float:
    return float(sum(p.length for p in paths))


# ---------------------------------------------------------------------------------------------
# Plan file


def save_plan(
    path: str | Path,
    graph: ConstraintGraph,
    paths: Sequence[ConstrainedPath],
    metadata: dict[str, Any] | None = None,
    step: float = 0.01,
    limits: Any = None,
) -> tuple[Path, Path]:
    """Write ``<path>.json`` and ``<path>.npz`` (see the module docstring for the format).
    ``limits`` (:class:`marionette.planning.timing.Limits`): also time every sample."""
    path = Path(path)
    base = path.with_suffix("") if path.suffix in (".json", ".npz") else path
    json_path, npz_path = base.with_suffix(".json"), base.with_suffix(".npz")
    problem = graph.problem
    arrays: dict[str, np.ndarray] = {}
    entries = []
    sampled = [p.sample(step) for p in paths]
    durations: list[float] = []
    if limits is not None:
        from marionette.planning.timing import time_parameterize

        times, durations = time_parameterize(paths, limits, [s for s, _ in sampled])
        for i, t in enumerate(times):
            arrays[f"t_{i}"] = t
    for i, p in enumerate(paths):
        s, qs = sampled[i]
        arrays[f"s_{i}"] = s
        arrays[f"path_{i}"] = qs
        e = p.edge
        top = e.parent if e.parent is not None else e
        src = graph.state_of(p.start)
        dst = graph.state_of(p.end)
        entries.append(
            {
                "index": i,
                "transition": e.name,
                "parent_transition": top.name,
                "from_state": e.from_state.name,
                "to_state": e.to_state.name,
                "containing_state": e.containing.name,
                "start_state": src.name if src is not None else None,
                "end_state": dst.name if dst is not None else None,
                "grasps": e.containing.grasps,
                "constraints": [c.name for c in e.path_constraints()],
                "rhs": p.rhs,
                "length": p.length,
                "num_samples": len(s),
                "q_start": p.start.tolist(),
                "q_end": p.end.tolist(),
            }
        )
        if durations:
            entries[-1]["duration"] = durations[i]
    doc = {
        "format": PLAN_FORMAT,
        "problem": {
            "name": problem.name,
            "source": str(problem.source) if problem.source else None,
            "nq": problem.nq,
            "nv": problem.nv,
            "configuration_layout": problem.configuration_layout(),
            "q_init": problem.q_init.tolist() if problem.q_init is not None else None,
            "q_goal": problem.q_goal.tolist() if problem.q_goal is not None else None,
            "grippers": {
                g.name: {"frame": problem.model.frames[g.frame_id].name, "clearance": g.clearance}
                for g in problem.grippers.values()
            },
            "handles": {
                h.name: {"object": h.object, "clearance": h.clearance, "mask": list(h.mask)}
                for h in problem.handles.values()
            },
        },
        "graph": graph.describe(),
        "sampling_step": step,
        "timed": bool(durations),
        "arrays": npz_path.name,
        "paths": entries,
        "metadata": metadata or {},
    }
    json_path.write_text(json.dumps(doc, indent=1))
    # allow_pickle spelled out (numpy's default) so that **arrays cannot be read as filling it.
    np.savez_compressed(npz_path, allow_pickle=True, **arrays)
    return json_path, npz_path


class Plan:
    """A loaded plan: ``doc`` (the JSON), ``paths`` (list of (s, q) arrays, one per path) and,
    for a timed plan, ``times`` (one t array per path, absolute, in seconds; else None)."""

    def __init__(
        self,
        doc: dict[str, Any],
        arrays: list[tuple[np.ndarray, np.ndarray]],
        times: list[np.ndarray] | None = None,
    ) -> None:
        self.doc = doc
        self.paths = arrays
        self.times = times

    @property
    def transitions(self) -> list[str]:
        return [p["transition"] for p in self.doc["paths"]]

    def configurations(self) -> np.ndarray:
        """All sampled configurations, in order (k x nq)."""
        return np.vstack([q for _, q in self.paths])


def load_plan(path: str | Path) -> Plan:
    """Read a plan written by :func:`save_plan` (``.json`` path or the common stem)."""
    path = Path(path)
    json_path = path if path.suffix == ".json" else path.with_suffix(".json")
    doc = json.loads(json_path.read_text())
    if doc.get("format") != PLAN_FORMAT:
        raise ValueError(f"{json_path}: not a {PLAN_FORMAT} file (format={doc.get('format')!r})")
    npz = np.load(json_path.parent / doc["arrays"])
    n = len(doc["paths"])
    arrays = [(npz[f"s_{i}"], npz[f"path_{i}"]) for i in range(n)]
    times = [npz[f"t_{i}"] for i in range(n)] if doc.get("timed") else None
    return Plan(doc, arrays, times)
