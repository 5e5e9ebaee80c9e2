"""Path optimisation that keeps transition semantics (the timing of the result:
:mod:`marionette.planning.timing`).

A plan is a sequence of elementary paths, each in one transition leaf (same transition, same
right-hand sides: the grasp held, the objects' placements).  Every operation here replaces a
stretch of the plan by paths of the same kind, each re-validated with the certified continuous
validation of ``collision.py``, so what a controller will execute (which transition, holding
what, where) is unchanged:

* :func:`vertex_shortcut` (HPP's SimpleShortcut): the shortest chain of transitions between
  the plan's vertices; removes the roadmap's detours;
* :func:`graph_shortcut` (HPP's RandomShortcut with the graph steering method): two random
  points joined by a transition between their states; removes release / re-grasp detours.
  Points are drawn on free motions only, never on approaches, so approach axes are kept;
* :func:`random_shortcut`: two random points of a run of paths in one leaf joined by that
  leaf's straight constrained path;
* :func:`partial_shortcut` (HPP's PartialShortcut): in a leaf of free joints (explicit
  constraints only), one random joint made linear between two random points, the others kept;
* :func:`optimize_paths`: the first once, then the three others in rounds until no progress.

"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from marionette.planning.collision import CollisionChecker
from marionette.planning.graph import ConstraintGraph
from marionette.planning.path import ConstrainedPath


def _leaf_key(p: ConstrainedPath) -> tuple:
    return (
        p.edge.name,
        tuple(
            np.round(
                np.concatenate([np.ravel(x) for group in p.rhs_state[:2] for x in group])
                if p.rhs_state[0] or p.rhs_state[1]
                else np.zeros(0),
                9,
            )
        ),
    )


def _runs(paths: list[ConstrainedPath]) -> list[tuple[int, int]]:
    """[i, j) ranges of consecutive paths in one leaf."""
    runs = []
    i = 0
    while i < len(paths):
        j = i + 1
        k = _leaf_key(paths[i])
        while j < len(paths) and _leaf_key(paths[j]) == k:
            j += 1
        runs.append((i, j))
        i = j
    return runs


def _cut_run(run, cum, a, b) -> list[ConstrainedPath]:
    out = []
    for i, p in enumerate(run):
        lo, hi = max(a, cum[i]), min(b, cum[i + 1])
        if hi - lo > 1e-12:
            # Snap to the path's own ends (cumulated sums round): its ends are exact.
            lo_s = 0.0 if lo - cum[i] < 1e-9 else lo - cum[i]
            hi_s = p.length if cum[i + 1] - hi < 1e-9 else hi - cum[i]
            out.append(p if (lo_s == 0.0 and hi_s == p.length) else p.extract(lo_s, hi_s))
    return out


def _drop_empty(paths: list[ConstrainedPath]) -> list[ConstrainedPath]:
    """Paths of no length dropped, the plan kept continuous to the bit. The length counts the
    free coordinates only: a dropped path may still move explicit ones (an object's pose
    substituted anew, ~1e-10), so the next kept path starts where the dropped one did (the last
    one ends where the plan ends)."""
    if not paths:
        return []
    out: list[ConstrainedPath] = []
    anchor = paths[0].start
    for p in paths:
        if p.length <= 1e-9:
            continue
        if not np.array_equal(p.start, anchor) and np.abs(p.start - anchor).max() < 1e-8:
            p = _with_ends(p, anchor, p.end)
        out.append(p)
        anchor = p.end
    if not out:
        return list(paths[:1])
    last = out[-1]
    if (
        not np.array_equal(last.end, paths[-1].end)
        and np.abs(last.end - paths[-1].end).max() < 1e-8
    ):
        out[-1] = _with_ends(last, last.start, paths[-1].end)
    return out


def _with_ends(p: ConstrainedPath, start: np.ndarray, end: np.ndarray) -> ConstrainedPath:
    """``p`` with its first and last points replaced (by configurations within rounding of
    them), under the same right-hand sides."""
    points = p.points.copy()
    points[0], points[-1] = start, end
    p.projector.restore_rhs(p.rhs_state)
    return ConstrainedPath(p.edge, points, p.projector, p.rhs)


def _cuts_clear(
    checker: CollisionChecker, path: ConstrainedPath, cuts: Sequence[np.ndarray]
) -> bool:
    """Do the new path ends cut out of ``path`` keep its transition's clearance? A path is
    excused from the clearance at an end already closer (a given start, goal or waypoint): a
    cut there would pass that excuse on, and shortcut after shortcut pull the motion against
    the obstacle."""
    return all(checker.is_clear(q, path) for q in cuts)


def vertex_shortcut(
    paths: list[ConstrainedPath],
    graph: ConstraintGraph,
    checker: CollisionChecker,
) -> list[ConstrainedPath]:
    """HPP's SimpleShortcut over the plan's vertices: every pair of vertices (starts of paths
    that are not approaches, and the goal) is joined, when possible, by a transition between
    their states (``graph.edges_between``: a loop, or a grasp / release with its waypoints
    regenerated), and the shortest chain from start to goal is kept (Dijkstra).  Removes the
    detours a roadmap leaves (an approach abandoned then resumed, a transit there and back)."""
    if len(paths) < 3:
        return list(paths)
    starts = [i for i, p in enumerate(paths) if not p.edge.short] + [len(paths)]
    if starts[0] != 0:
        starts.insert(0, 0)
    qs = [paths[i].start if i < len(paths) else paths[-1].end for i in starts]
    states = [graph.state_of(q) for q in qs]
    cum = np.concatenate([[0.0], np.cumsum([p.length for p in paths])])
    n = len(starts)
    # best[k]: (length, chain of paths) from vertex 0 to vertex k; vertices are in plan order,
    # so one forward pass is Dijkstra on this acyclic graph.
    best: list[tuple[float, list[ConstrainedPath]]] = [
        (0.0 if k == 0 else math.inf, []) for k in range(n)
    ]
    for k in range(n - 1):
        lk, chain = best[k]
        if not math.isfinite(lk):
            continue
        # the plan's own pieces to the next vertex
        nxt = (lk + cum[starts[k + 1]] - cum[starts[k]], chain + paths[starts[k] : starts[k + 1]])
        if nxt[0] < best[k + 1][0]:
            best[k + 1] = nxt
        for m in range(k + 2, n):
            original = cum[starts[m]] - cum[starts[k]]
            state_k, state_m = states[k], states[m]
            if state_k is None or state_m is None:
                continue
            for edge in graph.edges_between(state_k, state_m):
                new = edge.build(qs[k], qs[m])
                if not new:
                    continue
                length = sum(p.length for p in new)
                if length >= original - 1e-9 or lk + length >= best[m][0]:
                    continue
                if all(checker.validate(p, prefix=False)[0] for p in new):
                    best[m] = (lk + length, chain + new)
                    break
    return _drop_empty(best[-1][1]) if math.isfinite(best[-1][0]) else list(paths)


def random_shortcut(
    paths: list[ConstrainedPath],
    checker: CollisionChecker,
    rng: np.random.Generator,
    iterations: int = 40,
) -> list[ConstrainedPath]:
    """Random shortcut within transition leaves (see the module docstring): a run of paths of
    one leaf, two arc lengths in it, the part between them replaced by the leaf's straight
    constrained path when it is collision-free and shorter."""
    paths = list(paths)
    for _ in range(iterations):
        runs = _runs(paths)
        candidates = [r for r in runs if sum(p.length for p in paths[r[0] : r[1]]) > 1e-6]
        if not candidates:
            break
        i0, i1 = candidates[int(rng.integers(len(candidates)))]
        run = paths[i0:i1]
        cum = np.concatenate([[0.0], np.cumsum([p.length for p in run])])
        total = cum[-1]
        a, b = sorted(rng.random(2) * total)
        if b - a < 1e-3 * max(total, 1e-9):
            continue
        head = _cut_run(run, cum, 0.0, a)
        tail = _cut_run(run, cum, b, total)
        qa = head[-1].end if head else run[0].start
        qb = tail[0].start if tail else run[-1].end
        if not _cuts_clear(checker, run[0], [q for q, cut in ((qa, head), (qb, tail)) if cut]):
            continue
        new = run[0].edge.build(qa, qb)
        if not new or len(new) != 1:
            continue
        sc = new[0]
        if sc.length >= (b - a) - 1e-9:
            continue
        if not checker.validate(sc, prefix=False)[0]:
            continue
        paths = paths[:i0] + head + [sc] + tail + paths[i1:]
    return _drop_empty(paths)


def graph_shortcut(
    paths: list[ConstrainedPath],
    graph: ConstraintGraph,
    checker: CollisionChecker,
    rng: np.random.Generator,
    iterations: int = 40,
) -> list[ConstrainedPath]:
    """Random shortcut across transitions (HPP's graph steering method): two random points of
    the plan, in the graph states s1 and s2, are joined by a transition from s1 to s2 whose leaf
    holds both (a loop keeps the grasps and placements, a grasp transition regenerates its
    pre-grasp waypoints); it replaces the part in between when it is valid and shorter."""
    paths = list(paths)
    for _ in range(iterations):
        cand = [i for i, p in enumerate(paths) if not p.edge.short and p.length > 1e-9]
        if len(cand) < 1:
            break
        cum = np.concatenate([[0.0], np.cumsum([p.length for p in paths])])
        picks = sorted(
            (int(i), float(rng.random()) * paths[i].length) for i in rng.choice(cand, size=2)
        )
        (ia, sa), (ib, sb) = picks
        a, b = cum[ia] + sa, cum[ib] + sb
        if b - a < 1e-6:
            continue
        head, tail = _cut_run(paths, cum, 0.0, a), _cut_run(paths, cum, b, cum[-1])
        # The ends of the cut pieces are the shortcut's ends: the plan stays continuous.
        qa = head[-1].end if head else paths[0].start
        qb = tail[0].start if tail else paths[-1].end
        if not _cuts_clear(checker, paths[ia], [qa] if head else []):
            continue
        if not _cuts_clear(checker, paths[ib], [qb] if tail else []):
            continue
        s1, s2 = graph.state_of(qa), graph.state_of(qb)
        if s1 is None or s2 is None:
            continue
        for edge in graph.edges_between(s1, s2):
            new = edge.build(qa, qb)
            if not new:
                continue
            if sum(p.length for p in new) >= b - a - 1e-9:
                continue
            if all(checker.validate(p, prefix=False)[0] for p in new):
                paths = head + new + tail
                break
    return _drop_empty(paths)


def partial_shortcut(
    paths: list[ConstrainedPath],
    checker: CollisionChecker,
    rng: np.random.Generator,
    iterations: int = 40,
) -> list[ConstrainedPath]:
    """HPP's PartialShortcut within leaves of free joints: a run of paths of one such leaf, a
    random joint and two arc lengths a < b; that joint moves linearly (in the run's arc length)
    from its value at a to its value at b while the others keep their motion; the explicit
    constraints are substituted at every vertex.  Kept when every new piece is collision-free
    and the run gets shorter.  Joints that wander while the others need the whole run are what
    a full shortcut cannot straighten."""
    paths = list(paths)
    for _ in range(iterations):
        runs = [
            r
            for r in _runs(paths)
            if checker.leaf_free_joints(paths[r[0]].projector) is not None
            and all(len(p.points) == 2 for p in paths[r[0] : r[1]])
            and sum(p.length for p in paths[r[0] : r[1]]) > 1e-6
        ]
        if not runs:
            break
        i0, i1 = runs[int(rng.integers(len(runs)))]
        run = paths[i0:i1]
        projector = run[0].projector
        free = checker.leaf_free_joints(projector)
        assert free is not None  # runs keep only leaves of free joints
        joint = int(free[int(rng.integers(len(free)))])
        cum = np.concatenate([[0.0], np.cumsum([p.length for p in run])])
        a, b = sorted(rng.random(2) * cum[-1])
        if b - a < 1e-3 * cum[-1]:
            continue
        head = _cut_run(run, cum, 0.0, a)
        tail = _cut_run(run, cum, b, cum[-1])
        middle = _cut_run(run, cum, a, b)
        if not middle:
            continue
        verts = [middle[0].start] + [p.end for p in middle]
        s = np.concatenate([[0.0], np.cumsum([p.length for p in middle])])
        x0, x1 = verts[0][joint], verts[-1][joint]
        new_verts = [verts[0]]
        projector.restore_rhs(run[0].rhs_state)
        for v, si in zip(verts[1:-1], s[1:-1]):
            q = v.copy()
            q[joint] = x0 + (x1 - x0) * si / s[-1]
            projector.apply_explicit(q)
            new_verts.append(q)
        new_verts.append(verts[-1])
        rhs = run[0].rhs
        new = [
            ConstrainedPath(run[0].edge, np.array([u, w]), projector, rhs)
            for u, w in zip(new_verts, new_verts[1:])
        ]
        if sum(p.length for p in new) >= s[-1] - 1e-9:
            continue
        if not _cuts_clear(checker, run[0], new_verts[1:-1]):
            continue
        if not all(checker.validate(p, prefix=False)[0] for p in new):
            continue
        paths = paths[:i0] + head + new + tail + paths[i1:]
    return _merge_collinear(_drop_empty(paths))


def _merge_collinear(paths: list[ConstrainedPath]) -> list[ConstrainedPath]:
    """Consecutive straight paths of one leaf that continue in the same direction become one
    (fewer stops in the time parameterisation, same geometry)."""
    out: list[ConstrainedPath] = []
    for p in paths:
        if out and len(p.points) == 2 and len(out[-1].points) == 2:
            prev = out[-1]
            if _leaf_key(prev) == _leaf_key(p) and prev.edge is p.edge:
                model = p.model
                free = p.projector.free_idx
                d1 = pin.difference(model, prev.start, prev.end)[free]
                d2 = pin.difference(model, p.start, p.end)[free]
                n1, n2 = np.linalg.norm(d1), np.linalg.norm(d2)
                if n1 > 0 and n2 > 0 and d1.dot(d2) > (1 - 1e-9) * n1 * n2:
                    prev.projector.restore_rhs(prev.rhs_state)
                    out[-1] = ConstrainedPath(
                        prev.edge, np.array([prev.start, p.end]), prev.projector, prev.rhs
                    )
                    continue
        out.append(p)
    return out


def optimize_paths(
    paths: list[ConstrainedPath],
    graph: ConstraintGraph,
    checker: CollisionChecker,
    rng: np.random.Generator,
    iterations: int = 60,
) -> list[ConstrainedPath]:
    """Shortcut across transitions, then within leaves (full and partial shortcuts), in rounds
    of ``iterations`` attempts each, until a round gains less than 1 % (at most 4 rounds)."""
    if iterations <= 0 or not paths:
        return list(paths)
    paths = vertex_shortcut(paths, graph, checker)
    length = sum(p.length for p in paths)
    for _ in range(4):
        paths = graph_shortcut(paths, graph, checker, rng, iterations)
        paths = random_shortcut(paths, checker, rng, iterations)
        paths = partial_shortcut(paths, checker, rng, iterations)
        new = sum(p.length for p in paths)
        if new > 0.99 * length:
            break
        length = new
    return paths


def arm_path_length(paths: Sequence[ConstrainedPath], arm_q: Sequence[int], step: float = 0.01):
    """Sum of |delta q| over the arm joints (q indices ``arm_q``), sampled every ``step`` of arc
    length (bench_hpp measures HPP's paths the same way)."""
    total = 0.0
    idx = list(arm_q)
    for p in paths:
        _, qs = p.sample(step)
        total += float(np.linalg.norm(np.diff(qs[:, idx], axis=0), axis=1).sum())
    return total
