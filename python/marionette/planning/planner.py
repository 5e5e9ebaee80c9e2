"""Manipulation-RRT (thesis Algorithm 2, §3.2.3; HPP ``ManipulationPlanner``) and random shortcut.

One step: draw q_rand; for every connected component of the roadmap and every state, take the
node of that state nearest to q_rand, sample an outgoing transition of the state (by weight),
extend along it (project q_rand onto the destination state with the transition's
right-hand side taken from the node, build the constrained path, keep its collision-free
prefix); then try to connect the new nodes to each other and to the other components through a
transition joining their states.  The query is solved when the initial and a goal
configuration share a component; the result is the roadmap path between them, a sequence of
elementary paths, each in one transition (``optimize.py`` shortens it).

Two mechanisms beyond HPP 9's planner.  Level-set transitions (``graph.LevelSetEdge``, HPP's
``LevelSetEdge``) put an object down exactly where another component holds it, so components
come to share a leaf.  And when two nodes of different components share a leaf but the straight
path between them collides, they are joined by RRT-Connect inside that leaf (OMPL, in C++:
``CollisionChecker.plan_in_leaf``) -- HPP only tries straight paths there, and a cluttered leaf
then keeps its components apart until a lucky straight line appears.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
import time
from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np
import pinocchio as pin

from marionette.planning.collision import CollisionChecker
from marionette.planning.graph import (
    ConstraintGraph,
    Edge,
    LeafEdge,
    LevelSetEdge,
    State,
    WaypointEdge,
)
from marionette.planning.path import ConstrainedPath
from marionette.planning.problem import ManipulationProblem, sample_configuration
from marionette.planning.query import PlanningError, collision_message, no_state_message

__all__ = ["ManipulationRRT", "PlanResult", "PlanningError", "Roadmap"]


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


class _Reversed:
    """The paths of a roadmap edge taken backwards, reversed only when a solution uses them."""

    def __init__(self, paths: list[ConstrainedPath]) -> None:
        self.paths = paths
        self.length = float(sum(p.length for p in paths))

    def build(self) -> list[ConstrainedPath]:
        return [p.reverse() for p in reversed(self.paths)]


class Roadmap:
    """Nodes (with their graph state), edges carrying paths, connected components.

    Components are kept up to date as edges join them (members and members per state, the
    smaller merged into the larger), so that each planning step reads them in O(components).
    """

    def __init__(self, nq: int) -> None:
        self.nodes: list[Node] = []
        self._q = np.zeros((64, nq))
        self.adjacency: dict[int, list[tuple[int, list[ConstrainedPath] | _Reversed]]] = {}
        self._cc: list[int] = []  # union-find parents
        self._members: dict[int, list[int]] = {}  # root -> node indices
        self._by_state: dict[int, dict[int, list[int]]] = {}  # root -> id(state) -> indices
        self._in_state: dict[int, list[int]] = {}  # id(state) -> indices

    def add_node(self, q: np.ndarray, state: State) -> Node:
        n = Node(q.copy(), state, len(self.nodes))
        if n.index >= len(self._q):
            self._q = np.vstack([self._q, np.zeros_like(self._q)])
        self._q[n.index] = q
        self.nodes.append(n)
        self.adjacency[n.index] = []
        self._cc.append(n.index)
        self._members[n.index] = [n.index]
        self._in_state.setdefault(id(state), []).append(n.index)
        self._by_state[n.index] = {id(state): [n.index]}
        return n

    def component(self, i: int) -> int:
        while self._cc[i] != i:
            self._cc[i] = self._cc[self._cc[i]]
            i = self._cc[i]
        return i

    def add_edge(self, a: Node, b: Node, paths: list[ConstrainedPath]) -> None:
        """Paths a -> b; b -> a is the same motion backwards, built when a query uses it."""
        self.adjacency[a.index].append((b.index, paths))
        self.adjacency[b.index].append((a.index, _Reversed(paths)))
        ca, cb = self.component(a.index), self.component(b.index)
        if ca == cb:
            return
        if len(self._members[ca]) < len(self._members[cb]):
            ca, cb = cb, ca
        self._cc[cb] = ca
        self._members[ca] += self._members.pop(cb)
        into = self._by_state[ca]
        for sid, idx in self._by_state.pop(cb).items():
            into.setdefault(sid, []).extend(idx)

    def nodes_in_state(self, state: State) -> list[int]:
        """Every node of ``state`` (read only)."""
        return self._in_state.get(id(state), [])

    def components(self) -> dict[int, list[int]]:
        """Root -> node indices of every connected component (read only)."""
        return self._members

    def members_by_state(self, root: int) -> dict[int, list[int]]:
        """id(state) -> node indices of the component ``root`` (read only)."""
        return self._by_state[root]

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
        prev: dict[int, tuple[int, list[ConstrainedPath] | _Reversed]] = {}
        heap = [(0.0, start)]
        while heap:
            d, i = heapq.heappop(heap)
            if d > dist.get(i, math.inf):
                continue
            if i in goals:
                out: list[ConstrainedPath] = []
                while i != start:
                    j, paths = prev[i]
                    out = (paths.build() if isinstance(paths, _Reversed) else paths) + out
                    i = j
                return out
            for j, paths in self.adjacency[i]:
                nd = (
                    d + paths.length
                    if isinstance(paths, _Reversed)
                    else d + sum(p.length for p in paths)
                )
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
        leaf_iterations: int = 100,
        local_rate: float = 0.5,
        local_step: float = 0.25,
        extend_planning: bool = False,
        states: set[State] | None = None,
    ) -> None:
        self.problem = problem
        self.graph = graph
        self.checker = checker or CollisionChecker(problem)
        self.rng = np.random.default_rng(seed)
        self.connect_k = connect_k
        # RRT-Connect iterations of a connection planned inside a leaf (0: straight paths only).
        self.leaf_iterations = leaf_iterations
        self.local_rate = local_rate
        self.local_step = local_step
        self.extend_planning = extend_planning
        # Extensions only along transitions into these states (a guided leg's states); None: all.
        self.states = states
        self.roadmap = Roadmap(problem.nq)
        self._edge_tables: dict[int, tuple[list[Edge], np.ndarray]] = {}
        self._leaf_values: dict[tuple, tuple] = {}  # (objects, node) -> rounded poses
        self._leaf_free: dict[tuple, bool] = {}  # (objects, leaf, other objects) -> no collision
        self.leaf_draws = 20  # rejection draws of a level-set leaf
        # id(state) -> (node indices, their leaf vectors (rows)): the leaf index of connections
        self._leaves: dict[int, tuple[list[int], np.ndarray]] = {}
        self._node_leaves: dict[int, np.ndarray | None] = {}
        self.stats: Counter = Counter()
        self._q_rand = np.zeros(problem.nq)

    # ------------------------------------------------------------------------------ query
    def _add_query_node(self, q: np.ndarray, what: str) -> Node:
        state = self.graph.state_of(q)
        if state is None:
            raise PlanningError(no_state_message(self.graph, q, what))
        if not self.checker.is_valid(q, self.checker.grasp_contact_pairs(state.grasps)):
            raise PlanningError(collision_message(self.checker, q, what))
        return self._add_node(q, state)

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
            blocked = self._connect(init, g)
            if not self._connected(init, g) and blocked is not None:
                self._plan_connect(init, g, blocked)
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
        for comp in list(rm.components()):
            for idx in list(rm.members_by_state(comp).values()):
                near = rm.nodes[rm.nearest(q_rand, idx)[0]]
                target = q_rand
                if self.local_rate > 0 and self.rng.random() < self.local_rate:
                    # A sample near q_near on its way to q_rand: projections started there give
                    # the nearby solutions (the IK branch the arm is on), whose straight paths
                    # are short and mostly collision-free; the other extensions keep reaching
                    # anywhere (probabilistic completeness).
                    target = pin.interpolate(
                        self.problem.model, near.q, q_rand, self.local_step * self.rng.random()
                    )
                out = self.extend(near, target)
                if out is not None:
                    new.append((near, *out))
        new_nodes = []
        for near, paths, q_new, state in new:
            n = self._add_node(q_new, state)
            rm.add_edge(near, n, paths)
            new_nodes.append(n)
        if self._connect_new_nodes(new_nodes) == 0:
            self._connect_to_roadmap(new_nodes)

    def choose_edge(self, state: State) -> Edge | None:
        """An outgoing transition of ``state`` drawn with probability proportional to its weight."""
        table = self._edge_tables.get(id(state))
        if table is None:
            edges = [
                e
                for e in state.outgoing
                if e.weight > 0 and (self.states is None or e.to_state in self.states)
            ]
            table = (edges, np.cumsum([e.weight for e in edges]))
            self._edge_tables[id(state)] = table
        edges, cum = table
        if not edges:
            return None
        return edges[
            min(int(np.searchsorted(cum, self.rng.random() * cum[-1], "right")), len(edges) - 1)
        ]

    def leaf_configuration(self, near: Node, edge: LevelSetEdge) -> np.ndarray | None:
        """A configuration in the level-set edge's leaf state from another connected component
        than near's, each leaf weighted by its number of such nodes (HPP's leaf histogram) --
        among the leaves where the objects the edge puts down do not collide with the other
        objects as they are at near (a swap's goal spot stays taken until it is freed).
        Drawn by rejection: a uniform node of the state, redrawn while it is in near's
        component or its leaf is blocked."""
        rm = self.roadmap
        pool = rm.nodes_in_state(edge.leaf_state)
        comp = rm.component(near.index)
        objs = tuple(edge.leaf_objects)
        others = tuple(o for o in self.problem.objects if o not in objs)
        here = self._leaf_value(others, near.index) if objs else ()
        for _ in range(self.leaf_draws):
            if not pool:
                return None
            i = pool[int(self.rng.integers(len(pool)))]
            if rm.component(i) == comp:
                continue
            if not objs:
                return rm.nodes[i].q
            key = (objs, self._leaf_value(objs, i), here)
            free = self._leaf_free.get(key)
            if free is None:
                q = near.q.copy()
                for o in objs:
                    k = self.problem.objects[o].idx_q
                    q[k : k + 7] = rm.nodes[i].q[k : k + 7]
                free = not self.checker.objects_collide(q, list(objs))
                self._leaf_free[key] = free
            if free:
                return rm.nodes[i].q
        return None

    def _leaf_value(self, objects: tuple[str, ...], node: int) -> tuple:
        """Poses of ``objects`` at a node, rounded to the error threshold (a leaf histogram bin;
        cached per node)."""
        if not objects:
            return ()
        key = (objects, node)
        value = self._leaf_values.get(key)
        if value is None:
            q = self.roadmap.nodes[node].q
            idx = np.concatenate(
                [
                    np.arange(self.problem.objects[o].idx_q, self.problem.objects[o].idx_q + 7)
                    for o in objects
                ]
            )
            value = tuple(np.round(q[idx] / self.graph.error_threshold).astype(np.int64).tolist())
            self._leaf_values[key] = value
        return value

    def extend(self, near: Node, q_rand: np.ndarray):
        """(paths, q_new, state) of the collision-free part of an extension, or None."""
        edge = self.choose_edge(near.state)
        if edge is None:
            return None
        if isinstance(edge, LevelSetEdge):
            q_leaf = self.leaf_configuration(near, edge)
            if q_leaf is None:
                self.stats["level set: no leaf in another component"] += 1
                return None
            return self._extend_waypoints(near, edge, q_rand, q_leaf)
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
            self._keep_stopped(valid, p, s)
            self.stats["extension stopped by a collision"] += 1
            break
        else:
            if not self.checker.is_clear(valid[-1].end, valid[-1]):
                # a random target within the clearance would excuse every path from it
                self.stats["target closer than the clearance"] += 1
                return None
            self.stats["extension reached its target"] += 1
        if not valid:
            return None
        q_new = valid[-1].end
        state = self.graph.state_of(q_new)
        if state is None:
            self.stats["extension ended in no state"] += 1
            return None
        return valid, q_new.copy(), state

    def _keep_stopped(self, valid: list[ConstrainedPath], path: ConstrainedPath, s: float) -> None:
        """Appends to ``valid`` the part of ``path`` before the collision at arc length ``s``,
        when its end, a new node, keeps the clearance (a path from a start placed close may
        have come closer than it: such a node would excuse every path from it)."""
        if s <= 0:
            return
        part = path.extract(0.0, s * 0.999)
        if self.checker.is_clear(part.end, part):
            valid.append(part)
        else:
            self.stats["extension stopped closer than the clearance"] += 1

    def _extend_waypoints(
        self,
        near: Node,
        edge: WaypointEdge,
        q_rand: np.ndarray,
        q_leaf: np.ndarray | None = None,
    ):
        """Extension through waypoint states, one sub-transition at a time: each waypoint is
        generated only once the path to the previous one is known collision-free (HPP generates
        them all first; the collision-free prefix kept is the same, fewer projections wasted).
        ``q_leaf``: where a level-set sub-transition takes its leaf."""
        q_prev = near.q
        valid: list[ConstrainedPath] = []
        for sub in edge.sub_edges:
            q = q_rand.copy()
            if isinstance(sub, LeafEdge):
                res = sub.generate_target(q_prev, q, q_leaf)
            else:
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
                planned = self._plan_extension(sub, q_prev, q)
                if planned is not None:
                    valid += planned
                    q_prev = q
                    continue
                self._keep_stopped(valid, paths[0], s)
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

    def _plan_extension(
        self, sub: Edge, q_prev: np.ndarray, q: np.ndarray
    ) -> list[ConstrainedPath] | None:
        """The free motion of a grasp or release (its first sub-transition: transit to the
        pre-grasp, transfer to the pre-placement) planned by RRT-Connect in its leaf when the
        straight one collides and its target is collision-free; approaches stay straight."""
        if not self.extend_planning or self.leaf_iterations <= 0 or sub.short:
            return None
        if not self.checker.is_valid(q, self.checker.grasp_contact_pairs(sub.grasps)):
            return None
        paths = sub.plan(
            q_prev, q, self.checker, int(self.rng.integers(2**31)), self.leaf_iterations
        )
        self.stats["extension planned in a leaf" if paths else "leaf planning failed"] += 1
        return paths

    # ------------------------------------------------------------------------------ connect
    def _connect(self, a: Node, b: Node, waypoints: bool = True) -> Edge | None:
        """Joins a and b by the straight path of a transition between their states; returns the
        transition whose leaf holds both when that path collides (a planning candidate).
        ``waypoints``: also through grasp / release transitions (their waypoints generated from
        b, each sub-path validated as soon as it is built)."""
        blocked = None
        for edge in self.graph.edges_between(a.state, b.state):
            if isinstance(edge, WaypointEdge):
                if not waypoints:
                    continue
                paths = edge.build(a.q, b.q, self._valid_whole)
                if not paths:
                    continue
                self.roadmap.add_edge(a, b, paths)
                self.stats["connections"] += 1
                self.stats["connections through waypoints"] += 1
                return None
            paths = edge.build(a.q, b.q)
            if not paths:
                continue
            if all(self.checker.validate(p, prefix=False)[0] for p in paths):
                self.roadmap.add_edge(a, b, paths)
                self.stats["connections"] += 1
                return None
            blocked = blocked or edge
        return blocked

    def _valid_whole(self, path: ConstrainedPath) -> bool:
        return self.checker.validate(path, prefix=False)[0]

    def _plan_connect(self, a: Node, b: Node, edge: Edge) -> bool:
        """Joins a and b inside the leaf of ``edge`` by RRT-Connect (the per-transition planner)
        when the straight path collides."""
        if self.leaf_iterations <= 0 or isinstance(edge, WaypointEdge):
            return False
        paths = edge.plan(
            a.q, b.q, self.checker, int(self.rng.integers(2**31)), self.leaf_iterations
        )
        if not paths:
            self.stats["leaf planning failed"] += 1
            return False
        self.roadmap.add_edge(a, b, paths)
        self.stats["connections planned in a leaf"] += 1
        return True

    def _connected(self, a: Node, b: Node) -> bool:
        return self.roadmap.component(a.index) == self.roadmap.component(b.index)

    def _connect_new_nodes(self, nodes: list[Node]) -> int:
        count = 0
        for i, a in enumerate(nodes):
            for b in nodes[i + 1 :]:
                if self._connected(a, b):
                    continue
                # One direction, as HPP: every transition has its reverse.
                blocked = self._connect(a, b)
                if self._connected(a, b) or (blocked and self._plan_connect(a, b, blocked)):
                    count += 1
        return count

    def _connect_to_roadmap(self, nodes: list[Node]) -> int:
        """Each new node to the k nearest nodes of every other component (straight paths, as
        HPP), and to the nearest node of that component in its own leaf (same state, same
        right-hand sides: what a level-set transition produces); when all of those straight
        paths collide, RRT-Connect in the leaf shared with the nearest candidate."""
        count = 0
        rm = self.roadmap
        for a in nodes:
            same_leaf = self._leaf_mates(a)
            for comp, members in list(rm.components().items()):
                if comp not in rm.components() or comp == rm.component(a.index):
                    continue
                candidate = None
                joined = False
                near = rm.nearest(a.q, members, self.connect_k)
                leaf_mates = [i for i in same_leaf if rm.component(i) == comp]
                if leaf_mates:
                    j = rm.nearest(a.q, leaf_mates)[0]
                    if j not in near:
                        near.append(j)
                        self.stats["same-leaf connection attempts"] += 1
                for rank, j in enumerate(near):
                    b = rm.nodes[j]
                    # Through grasp / release waypoints only to the nearest two (each try
                    # projects and validates a whole transition).
                    blocked = self._connect(a, b, waypoints=rank < 2)
                    if self._connected(a, b):
                        joined = True
                        break
                    if blocked is not None and candidate is None:
                        candidate = (b, blocked)
                if not joined and candidate is not None:
                    joined = self._plan_connect(a, *candidate)
                if joined:  # as HPP: one connection per new node
                    count += 1
                    break
        return count

    def _add_node(self, q: np.ndarray, state: State) -> Node:
        """A roadmap node, indexed by its leaf (:meth:`_leaf_vector`)."""
        n = self.roadmap.add_node(q, state)
        v = self._leaf_vector(n)
        if v is not None:
            idx, rows = self._leaves.get(id(state), ([], np.zeros((0, len(v)))))
            idx.append(n.index)
            if len(idx) > len(rows):
                rows = np.vstack([rows, np.zeros((max(len(rows), 16), len(v)))])
            rows[len(idx) - 1] = v
            self._leaves[id(state)] = (idx, rows)
        return n

    def _leaf_mates(self, a: Node) -> list[int]:
        """Nodes of a's state whose leaf is a's within 10 error thresholds (the connection's
        can_connect then decides exactly)."""
        entry = self._leaves.get(id(a.state))
        v = self._leaf_vector(a)
        if entry is None or v is None:
            return []
        idx, rows = entry
        d = np.max(np.abs(rows[: len(idx)] - v), axis=1)
        return [idx[k] for k in np.flatnonzero(d < 10 * self.graph.error_threshold)]

    def _leaf_vector(self, a: Node) -> np.ndarray | None:
        """Right-hand sides of a's state loop at a (locked values with quaternions of positive
        w, parametrised constraints), None for a state without leaves; cached per node."""
        if a.index in self._node_leaves:
            return self._node_leaves[a.index]
        loops = [
            e for e in self.graph.edges_between(a.state, a.state) if e.from_state is e.to_state
        ]
        v = None
        if loops:
            proj = loops[0].path_projector
            proj.set_rhs_from(a.q)
            parts = []
            for lk in proj.locked:
                x = lk.value.copy()
                if lk.nq == 7 and x[6] < 0:
                    x[3:] = -x[3:]
                parts.append(x)
            parts += [c.rhs for c in proj.parametrised]
            parts += [np.array([float(p.pair)]) for p in proj.placements]
            if parts:
                v = np.concatenate(parts)
        self._node_leaves[a.index] = v
        return v
