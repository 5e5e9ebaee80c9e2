"""Manipulation-RRT (thesis Algorithm 2, §3.2.3; HPP ``ManipulationPlanner``) and random shortcut.

One step: draw q_rand; for every connected component of the roadmap and every state, take the
node of that state nearest to q_rand, sample an outgoing transition of the state (by weight),
extend along it (project q_rand onto the destination state with the transition's
right-hand side taken from the node, build the constrained path, keep its collision-free
prefix); then try to connect the new nodes to each other and to the other components through a
transition joining their states.  The query is solved when the initial and a goal
configuration share a component; the result is the roadmap path between them, a sequence of
elementary paths, each in one transition.

:func:`graph_shortcut` shortens it across transitions (two points joined by a transition
between their states, as HPP's graph steering method), which removes release / re-grasp
detours; :func:`random_shortcut` then shortens runs of paths within one transition leaf.  Both
keep the pre-grasp approaches and the placements.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np

from marionette.planning.collision import CollisionChecker
from marionette.planning.graph import ConstraintGraph, Edge, State, WaypointEdge
from marionette.planning.path import ConstrainedPath
from marionette.planning.problem import ManipulationProblem, sample_configuration


class PlanningError(RuntimeError):
    """A query that cannot be planned (start/goal in no state or in collision)."""


@dataclasses.dataclass
class Node:
    q: np.ndarray
    state: State
    index: int


@dataclasses.dataclass
class PlanResult:
    """Outcome of :meth:`ManipulationRRT.solve`."""

    success: bool
    paths: list[ConstrainedPath]
    iterations: int
    time_s: float
    nodes: int
    reason: str = ""
    statistics: dict = dataclasses.field(default_factory=dict)

    @property
    def transitions(self) -> list[str]:
        return [p.edge.name for p in self.paths]

    @property
    def length(self) -> float:
        return float(sum(p.length for p in self.paths))


class Roadmap:
    """Nodes (with their graph state), edges carrying paths, connected components."""

    def __init__(self, nq: int) -> None:
        self.nodes: list[Node] = []
        self._q = np.zeros((64, nq))
        self.adjacency: dict[int, list[tuple[int, list[ConstrainedPath]]]] = {}
        self._cc: list[int] = []  # union-find parents

    def add_node(self, q: np.ndarray, state: State) -> Node:
        n = Node(q.copy(), state, len(self.nodes))
        if n.index >= len(self._q):
            self._q = np.vstack([self._q, np.zeros_like(self._q)])
        self._q[n.index] = q
        self.nodes.append(n)
        self.adjacency[n.index] = []
        self._cc.append(n.index)
        return n

    def component(self, i: int) -> int:
        while self._cc[i] != i:
            self._cc[i] = self._cc[self._cc[i]]
            i = self._cc[i]
        return i

    def add_edge(self, a: Node, b: Node, paths: list[ConstrainedPath]) -> None:
        self.adjacency[a.index].append((b.index, paths))
        self.adjacency[b.index].append((a.index, [p.reverse() for p in reversed(paths)]))
        ca, cb = self.component(a.index), self.component(b.index)
        if ca != cb:
            self._cc[max(ca, cb)] = min(ca, cb)

    def components(self) -> dict[int, list[int]]:
        out: dict[int, list[int]] = {}
        for n in self.nodes:
            out.setdefault(self.component(n.index), []).append(n.index)
        return out

    def nearest(self, q: np.ndarray, indices: Sequence[int], k: int = 1) -> list[int]:
        """The k nodes among ``indices`` nearest to q (Euclidean in q; brute force is the fastest
        choice for roadmaps of a few hundred nodes)."""
        idx = np.asarray(indices)
        d = np.einsum("ij,ij->i", self._q[idx] - q, self._q[idx] - q)
        if k == 1:
            return [int(idx[int(np.argmin(d))])]
        order = np.argsort(d)[:k]
        return [int(idx[i]) for i in order]

    def shortest_path(self, start: int, goals: set[int]) -> list[ConstrainedPath] | None:
        """Dijkstra on path lengths."""
        dist = {start: 0.0}
        prev: dict[int, tuple[int, list[ConstrainedPath]]] = {}
        heap = [(0.0, start)]
        while heap:
            d, i = heapq.heappop(heap)
            if d > dist.get(i, math.inf):
                continue
            if i in goals:
                out: list[ConstrainedPath] = []
                while i != start:
                    j, paths = prev[i]
                    out = paths + out
                    i = j
                return out
            for j, paths in self.adjacency[i]:
                nd = d + sum(p.length for p in paths)
                if nd < dist.get(j, math.inf):
                    dist[j] = nd
                    prev[j] = (i, paths)
                    heapq.heappush(heap, (nd, j))
        return None


class ManipulationRRT:
    """Manipulation-RRT over a constraint graph (see the module docstring)."""

    def __init__(
        self,
        problem: ManipulationProblem,
        graph: ConstraintGraph,
        checker: CollisionChecker | None = None,
        seed: int = 0,
        connect_k: int = 7,
    ) -> None:
        self.problem = problem
        self.graph = graph
        self.checker = checker or CollisionChecker(problem)
        self.rng = np.random.default_rng(seed)
        self.connect_k = connect_k
        self.roadmap = Roadmap(problem.nq)
        self.stats: Counter = Counter()
        self._q_rand = np.zeros(problem.nq)

    # ------------------------------------------------------------------------------ query
    def _add_query_node(self, q: np.ndarray, what: str) -> Node:
        state = self.graph.state_of(q)
        if state is None:
            raise PlanningError(
                f"{what} configuration is in no state of the graph "
                f"(constraint errors above {self.graph.error_threshold})"
            )
        if not self.checker.is_valid(q, self.checker.grasp_contact_pairs(state.grasps)):
            raise PlanningError(
                f"{what} configuration is in collision: {self.checker.colliding_pairs(q)}"
            )
        return self.roadmap.add_node(q, state)

    def solve(
        self,
        q_init: np.ndarray,
        q_goals: Sequence[np.ndarray],
        max_iterations: int = 5000,
        timeout_s: float = 60.0,
        progress: Callable[[int, int, int], None] | None = None,
    ) -> PlanResult:
        """Plan from q_init to one of q_goals; ``progress(iteration, nodes, components)``."""
        t0 = time.perf_counter()
        init = self._add_query_node(np.asarray(q_init, dtype=float), "initial")
        goals = [self._add_query_node(np.asarray(q, dtype=float), "goal") for q in q_goals]
        goal_idx = {g.index for g in goals}
        for g in goals:
            self._connect(init, g)
        it = 0
        reason = ""
        while not self._solved(init, goal_idx):
            if it >= max_iterations:
                reason = f"no path after {it} iterations"
                break
            if time.perf_counter() - t0 > timeout_s:
                reason = f"no path after {timeout_s} s"
                break
            self.one_step()
            it += 1
            if progress is not None:
                progress(it, len(self.roadmap.nodes), len(self.roadmap.components()))
        elapsed = time.perf_counter() - t0
        if not self._solved(init, goal_idx):
            return PlanResult(
                False, [], it, elapsed, len(self.roadmap.nodes), reason, dict(self.stats)
            )
        paths = self.roadmap.shortest_path(init.index, goal_idx) or []
        return PlanResult(True, paths, it, elapsed, len(self.roadmap.nodes), "", dict(self.stats))

    def _solved(self, init: Node, goals: set[int]) -> bool:
        c = self.roadmap.component(init.index)
        return any(self.roadmap.component(g) == c for g in goals)

    # ------------------------------------------------------------------------------ one step
    def one_step(self) -> None:
        rm = self.roadmap
        q_rand = sample_configuration(self.problem, self.rng, self._q_rand)
        new: list[tuple[Node, list[ConstrainedPath], np.ndarray, State]] = []
        for _comp, members in rm.components().items():
            by_state: dict[int, list[int]] = {}
            for i in members:
                by_state.setdefault(id(rm.nodes[i].state), []).append(i)
            for idx in by_state.values():
                near = rm.nodes[rm.nearest(q_rand, idx)[0]]
                out = self.extend(near, q_rand)
                if out is not None:
                    new.append((near, *out))
        new_nodes = []
        for near, paths, q_new, state in new:
            n = rm.add_node(q_new, state)
            rm.add_edge(near, n, paths)
            new_nodes.append(n)
        if self._connect_new_nodes(new_nodes) == 0:
            self._connect_to_roadmap(new_nodes)

    def choose_edge(self, state: State) -> Edge | None:
        edges = [e for e in state.outgoing if e.weight > 0]
        if not edges:
            return None
        w = np.array([e.weight for e in edges])
        return edges[int(self.rng.choice(len(edges), p=w / w.sum()))]

    def extend(self, near: Node, q_rand: np.ndarray):
        """(paths, q_new, state) of the collision-free part of an extension, or None."""
        edge = self.choose_edge(near.state)
        if edge is None:
            return None
        if isinstance(edge, WaypointEdge):
            return self._extend_waypoints(near, edge, q_rand)
        q = q_rand.copy()
        res = edge.generate_target(near.q, q)
        if not res:
            self.stats[f"projection failed: {res.status.name}"] += 1
            return None
        if np.linalg.norm(q - near.q) < self.graph.error_threshold:
            self.stats["target equals start"] += 1
            return None
        paths = edge.build(near.q, q)
        if not paths:
            self.stats["path could not be built"] += 1
            return None
        valid: list[ConstrainedPath] = []
        for p in paths:
            ok, s = self.checker.validate(p)
            if ok:
                valid.append(p)
                continue
            if s > 0:
                valid.append(p.extract(0.0, s * 0.999))
            self.stats["extension stopped by a collision"] += 1
            break
        else:
            self.stats["extension reached its target"] += 1
        if not valid:
            return None
        q_new = valid[-1].end
        state = self.graph.state_of(q_new)
        if state is None:
            self.stats["extension ended in no state"] += 1
            return None
        return valid, q_new.copy(), state

    def _extend_waypoints(self, near: Node, edge: WaypointEdge, q_rand: np.ndarray):
        """Extension through waypoint states, one sub-transition at a time: each waypoint is
        generated only once the path to the previous one is known collision-free (HPP generates
        them all first; the collision-free prefix kept is the same, fewer projections wasted)."""
        q_prev = near.q
        valid: list[ConstrainedPath] = []
        for sub in edge.sub_edges:
            q = q_rand.copy()
            res = sub.generate_target(q_prev, q)
            if not res:
                self.stats[f"projection failed: {res.status.name}"] += 1
                break
            if np.linalg.norm(q - q_prev) < self.graph.error_threshold:
                continue
            paths = sub.build(q_prev, q)
            if not paths:
                self.stats["path could not be built"] += 1
                break
            ok, s = self.checker.validate(paths[0])
            if not ok:
                if s > 0:
                    valid.append(paths[0].extract(0.0, s * 0.999))
                self.stats["extension stopped by a collision"] += 1
                break
            valid.append(paths[0])
            q_prev = q
        else:
            self.stats["extension reached its target"] += 1
        if not valid:
            return None
        q_new = valid[-1].end
        state = self.graph.state_of(q_new)
        if state is None:
            self.stats["extension ended in no state"] += 1
            return None
        return valid, q_new.copy(), state

    # ------------------------------------------------------------------------------ connect
    def _connect(self, a: Node, b: Node) -> bool:
        for edge in self.graph.edges_between(a.state, b.state):
            paths = edge.build(a.q, b.q)
            if not paths:
                continue
            if all(self.checker.validate(p, prefix=False)[0] for p in paths):
                self.roadmap.add_edge(a, b, paths)
                self.stats["connections"] += 1
                return True
        return False

    def _connect_new_nodes(self, nodes: list[Node]) -> int:
        count = 0
        rm = self.roadmap
        for i, a in enumerate(nodes):
            for b in nodes[i + 1 :]:
                if rm.component(a.index) == rm.component(b.index):
                    continue
                if self._connect(a, b):  # one direction, as HPP: every transition has its reverse
                    count += 1
        return count

    def _connect_to_roadmap(self, nodes: list[Node]) -> int:
        count = 0
        rm = self.roadmap
        for a in nodes:
            for comp, members in rm.components().items():
                if comp == rm.component(a.index):
                    continue
                done = False
                for j in rm.nearest(a.q, members, self.connect_k):
                    b = rm.nodes[j]
                    if self._connect(
                        a, b
                    ):  # one direction, as HPP: every transition has its reverse
                        count += 1
                        done = True
                        break
                if done:
                    break
        return count


# ---------------------------------------------------------------------------------- shortcut
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


def random_shortcut(
    paths: list[ConstrainedPath],
    checker: CollisionChecker,
    rng: np.random.Generator,
    iterations: int = 40,
) -> list[ConstrainedPath]:
    """Random shortcut within transition leaves (see the module docstring).

    Consecutive paths of one leaf form a run; a shortcut picks a run and two arc lengths in it
    and replaces the part between them by the straight constrained path of that transition
    when it is collision-free and shorter."""
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
        edge = run[0].edge
        new = edge.build(qa, qb)
        if not new or len(new) != 1:
            continue
        sc = new[0]
        if sc.length >= (b - a) - 1e-9:
            continue
        if not checker.validate(sc, prefix=False)[0]:
            continue
        paths = paths[:i0] + head + [sc] + tail + paths[i1:]
    return [p for p in paths if p.length > 0.0 or len(paths) == 1]


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
    pre-grasp waypoints); it replaces the part in between when it is valid and shorter, which
    also removes useless release / re-grasp detours.  Points are only drawn on free motions
    (loops and first sub-transitions), never on approaches, so approach axes are kept."""
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
    return [p for p in paths if p.length > 0.0 or len(paths) == 1]


def _runs(paths: list[ConstrainedPath]) -> list[tuple[int, int]]:
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


def _eval_run(run, cum, s) -> np.ndarray:
    i = min(int(np.searchsorted(cum, s, side="right") - 1), len(run) - 1)
    return run[i].eval(s - cum[i])


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
