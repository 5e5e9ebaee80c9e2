"""Constraint graph (thesis §3.2.1, fig. 3.3-3.4): states, transitions and waypoint transitions.

A :class:`State` is a set of constraints (a configuration belongs to it when it satisfies
them).  An :class:`Edge` (transition) goes from one state to another and lies in a
*containing* state whose constraints hold all along it, plus its own parametrised constraints
(the foliation: placement or grasp complements) whose right-hand side is taken from the
configuration where the path starts (g(gamma(t)) = g(q0)).  A :class:`WaypointEdge` chains
sub-edges through waypoint states (pre-grasp, intersection, pre-placement).

Edges know how to generate a target configuration (project a sample onto the destination
state with the edge's right-hand side fixed: Algorithm 2's "extend along the transition") and
how to build the straight, constrained path between two configurations of their foliation leaf.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from marionette.planning.constraints import Constraint, ExplicitConstraint, PlacementComplement
from marionette.planning.path import ConstrainedPath, PathError
from marionette.planning.problem import ManipulationProblem
from marionette.planning.projector import LineSearch, ProjectionResult, Projector

AnyConstraint = Constraint | ExplicitConstraint


class GraphError(ValueError):
    """A malformed graph (unknown state, duplicate name, edge between unknown states)."""


class State:
    """A node of the constraint graph: a name, its constraints, and grasps (for people)."""

    def __init__(
        self,
        graph: ConstraintGraph,
        name: str,
        constraints: Sequence[AnyConstraint],
        waypoint: bool = False,
        priority: int = 0,
        grasps: dict[str, str] | None = None,
    ) -> None:
        self.graph = graph
        self.name = name
        self.constraints = list(constraints)
        self.waypoint = waypoint
        self.priority = priority
        self.grasps = dict(grasps or {})
        self.outgoing: list[Edge] = []
        self._projector: Projector | None = None

    @property
    def projector(self) -> Projector:
        if self._projector is None:
            self._projector = self.graph.make_projector(
                self.graph.constraints + self.constraints, f"state {self.name}"
            )
        return self._projector

    def contains(self, q: np.ndarray) -> bool:
        """Does q satisfy the state's constraints (within the graph's error threshold)?"""
        return self.projector.is_satisfied(q)

    def project(self, q: np.ndarray) -> ProjectionResult:
        """Project q (in place) onto the state."""
        return self.projector.project(q)

    def __repr__(self) -> str:
        return f"State({self.name!r})"


class Edge:
    """A transition ``name``: ``from_state`` -> ``to_state``, lying in ``containing``.

    ``constraints``: the edge's own parametrised constraints (complements), rhs from the start.
    ``weight``: probability weight when Manipulation-RRT samples an outgoing transition (0:
    never sampled, used only to connect).  ``short``: the target is generated from the start
    configuration rather than from the random sample (HPP ``setShort``), as for the straight
    approach from a pre-grasp to the grasp.
    """

    def __init__(
        self,
        graph: ConstraintGraph,
        name: str,
        from_state: State,
        to_state: State,
        containing: State,
        constraints: Sequence[AnyConstraint] = (),
        weight: float = 1.0,
        short: bool = False,
    ) -> None:
        self.graph = graph
        self.name = name
        self.from_state = from_state
        self.to_state = to_state
        self.containing = containing
        self.constraints = list(constraints)
        self.weight = weight
        self.short = short
        self.parent: WaypointEdge | None = None
        self.reverse_edge: Edge | None = None  # same constraints, opposite direction
        self._path_projector: Projector | None = None
        self._target_projector: Projector | None = None

    @property
    def grasps(self) -> dict[str, str]:
        """Grasps held at either end or along the transition (gripper -> handle); contact between
        these grippers and objects is the grasp, not a collision."""
        out: dict[str, str] = {}
        for s in (self.from_state, self.containing, self.to_state):
            out.update(s.grasps)
        return out

    # ---------------------------------------------------------------- projectors (lazy, cached)
    def path_constraints(self) -> list[AnyConstraint]:
        """Graph + edge + containing-state constraints: what holds along the path."""
        return _unique(self.graph.constraints + self.constraints + self.containing.constraints)

    def target_constraints(self) -> list[AnyConstraint]:
        """Path constraints + the destination state's: what the path's end satisfies."""
        return _unique(self.path_constraints() + self.to_state.constraints)

    @property
    def path_projector(self) -> Projector:
        if self._path_projector is None:
            self._path_projector = self.graph.make_projector(
                self.path_constraints(),
                f"path {self.name}",
                threshold=0.5 * self.graph.error_threshold,
            )
        return self._path_projector

    @property
    def target_projector(self) -> Projector:
        if self._target_projector is None:
            self._target_projector = self.graph.make_projector(
                self.target_constraints(), f"target {self.name}"
            )
        return self._target_projector

    # ---------------------------------------------------------------- planning operations
    def generate_target(self, q_start: np.ndarray, q: np.ndarray) -> ProjectionResult:
        """Project q (in place) onto the destination state with the edge's rhs from q_start."""
        proj = self.target_projector
        proj.set_rhs_from(q_start)
        if self.short:
            q[:] = q_start
        return proj.project(q)

    def can_connect(self, q1: np.ndarray, q2: np.ndarray) -> bool:
        """Are q1 and q2 on the same leaf of this edge's foliation (rhs from q1)?"""
        proj = self.path_projector
        proj.set_rhs_from(q1)
        return proj.is_satisfied(q1, self.graph.error_threshold) and proj.is_satisfied(
            q2, self.graph.error_threshold
        )

    def build(self, q1: np.ndarray, q2: np.ndarray) -> list[ConstrainedPath] | None:
        """Straight constrained path(s) q1 -> q2 in this edge, or None when not on one leaf."""
        if not self.can_connect(q1, q2):
            return None
        try:
            return [
                ConstrainedPath.build(self, q1, q2, self.path_projector, step=self.graph.path_step)
            ]
        except PathError:
            return None

    def plan(
        self, q1: np.ndarray, q2: np.ndarray, checker, seed: int, max_iterations: int = 200
    ) -> list[ConstrainedPath] | None:
        """Collision-free straight pieces q1 -> q2 in this edge's leaf found by RRT-Connect
        (``checker``: a :class:`marionette.planning.collision.CollisionChecker`), or None (not
        one leaf, a leaf with implicit constraints, or no path found within the iterations)."""
        if not self.can_connect(q1, q2):
            return None
        proj = self.path_projector  # right-hand sides from q1 (can_connect)
        pts = checker.plan_in_leaf(
            proj,
            checker.grasp_contact_pairs(self.grasps),
            q1,
            q2,
            seed,
            max_iterations,
            step=self.graph.path_step,
        )
        if pts is None:
            return None
        rhs = proj.rhs_vector()
        if proj.implicit:  # one progressively projected polyline
            return [ConstrainedPath(self, pts, proj, rhs)]
        return [ConstrainedPath(self, np.array([a, b]), proj, rhs) for a, b in zip(pts, pts[1:])]

    def __repr__(self) -> str:
        return f"Edge({self.name!r}: {self.from_state.name} -> {self.to_state.name})"


class WaypointEdge(Edge):
    """A transition through waypoint states (thesis fig. 3.4): sub-edges e_0 ... e_n.

    Generating its target projects the sample successively onto each waypoint state (HPP
    ``WaypointEdge::generateTargetConfig``); building it builds each sub-path.
    """

    def __init__(
        self,
        graph: ConstraintGraph,
        name: str,
        from_state: State,
        to_state: State,
        containing: State,
        sub_edges: Sequence[Edge],
        weight: float = 1.0,
    ) -> None:
        super().__init__(graph, name, from_state, to_state, containing, weight=weight)
        if not sub_edges:
            raise GraphError(f"{name}: a waypoint edge needs sub-edges")
        if sub_edges[0].from_state is not from_state or sub_edges[-1].to_state is not to_state:
            raise GraphError(f"{name}: sub-edges do not chain {from_state.name} -> {to_state.name}")
        for a, b in zip(sub_edges, sub_edges[1:]):
            if a.to_state is not b.from_state:
                raise GraphError(f"{name}: sub-edges {a.name} and {b.name} do not chain")
        self.sub_edges = list(sub_edges)
        for e in self.sub_edges:
            e.parent = self
        self.waypoints = [e.to_state for e in self.sub_edges[:-1]]
        self.last_waypoint_configs: list[np.ndarray] = []
        self._common: list[AnyConstraint] | None = None  # held by every sub-transition
        self._common_projector: Projector | None = None

    @property
    def path_projector(self) -> Projector:
        return self.sub_edges[0].path_projector

    @property
    def target_projector(self) -> Projector:
        return self.sub_edges[-1].target_projector

    def generate_target(self, q_start: np.ndarray, q: np.ndarray) -> ProjectionResult:
        q_prev = q_start
        configs = [q_start]
        result = None
        for e in self.sub_edges:
            q_next = q.copy()
            result = e.generate_target(q_prev, q_next)
            if not result:
                return result
            configs.append(q_next)
            q_prev = q_next
        q[:] = q_prev
        self.last_waypoint_configs = configs
        assert result is not None  # __init__ refuses a waypoint edge without sub-edges
        return result

    def common_leaf_projector(self) -> Projector | None:
        """The projector of the constraints every sub-transition holds (compiled on first use),
        None when they hold none in common."""
        if self._common is None:
            subs = self.sub_edges
            self._common = [c for c in subs[0].constraints if all(c in e.constraints for e in subs)]
            if self._common:
                self._common_projector = self.graph.make_projector(
                    self._common, f"common leaf {self.name}"
                )
        return self._common_projector

    def can_connect(self, q1: np.ndarray, q2: np.ndarray) -> bool:
        """Do q1 and q2 agree on what every sub-transition keeps constant (the placements of
        the objects the transition does not move)?  Necessary for a path q1 -> q2 in it."""
        proj = self.common_leaf_projector()
        if proj is None:
            return True
        proj.set_rhs_from(q1)
        return proj.is_satisfied(q2, self.graph.error_threshold)

    def build(
        self, q1: np.ndarray, q2: np.ndarray, accept: Callable | None = None
    ) -> list[ConstrainedPath] | None:
        """Sub-paths q1 -> w1 -> ... -> q2; waypoints generated from q2 unless cached.
        ``accept(path) -> bool`` (a validity check) is applied to each sub-path as soon as it is
        built: the first refused one ends the build (None) before the next is projected."""
        if not self.can_connect(q1, q2):
            return None
        n = len(self.sub_edges)
        cached = self.last_waypoint_configs
        if (
            len(cached) == n + 1
            and np.array_equal(cached[0], q1)
            and np.array_equal(cached[-1], q2)
        ):
            configs = cached
        else:
            configs = [q1]
            for e in self.sub_edges[:-1]:
                qn = q2.copy()
                if not e.generate_target(configs[-1], qn):
                    return None
                configs.append(qn)
            configs.append(q2)
        paths: list[ConstrainedPath] = []
        for e, a, b in zip(self.sub_edges, configs, configs[1:]):
            if np.array_equal(a, b):
                continue
            sub = e.build(a, b)
            if sub is None:
                return None
            if accept is not None and not all(accept(x) for x in sub):
                return None
            paths += sub
        return paths


class LeafEdge(Edge):
    """A sub-transition whose target also takes the right-hand sides of ``leaf`` constraints from a
    configuration ``q_leaf`` (HPP ``LevelSetEdge``'s parametrisation): the destination leaf is the
    one a configuration of another connected component lies on, instead of a random one.

    Its paths are those of ``base`` (same path constraints, same name in plans): only the target
    generation differs.
    """

    def __init__(self, base: Edge, leaf: Sequence[AnyConstraint]) -> None:
        super().__init__(
            base.graph,
            base.name + "_ls",
            base.from_state,
            base.to_state,
            base.containing,
            base.constraints,
            weight=base.weight,
            short=base.short,
        )
        self.base = base
        self.leaf = list(leaf)
        self.reverse_edge = base.reverse_edge

    def target_constraints(self) -> list[AnyConstraint]:
        return _unique(self.base.target_constraints() + self.leaf)

    @property
    def path_projector(self) -> Projector:
        return self.base.path_projector

    def generate_target(
        self, q_start: np.ndarray, q: np.ndarray, q_leaf: np.ndarray | None = None
    ) -> ProjectionResult:
        """Project q onto the destination with the edge's rhs from q_start and the leaf
        constraints' rhs from q_leaf (q_start's when None)."""
        proj = self.target_projector
        proj.set_rhs_from(q_start)
        if q_leaf is not None:
            proj.set_rhs_of(self.leaf, q_leaf)
        if self.short:
            q[:] = q_start
        return proj.project(q)

    def can_connect(self, q1: np.ndarray, q2: np.ndarray) -> bool:
        return self.base.can_connect(q1, q2)

    def build(self, q1: np.ndarray, q2: np.ndarray) -> list[ConstrainedPath] | None:
        return self.base.build(q1, q2)

    def plan(self, q1, q2, checker, seed: int, max_iterations: int = 200):
        return self.base.plan(q1, q2, checker, seed, max_iterations)


class LevelSetEdge(WaypointEdge):
    """HPP's level-set transition: the same motion as a (waypoint) transition, whose destination
    leaf is copied from a roadmap configuration in ``leaf_state`` of another connected component.

    A release that puts an object down exactly where another component has it (a swap's goal
    leaf, the pose under a stack) makes the two components share a leaf, so a transition of that
    leaf can join them; random placements never hit it (a leaf has measure zero).  ``leaf``: the
    parametrised constraints whose rhs is copied (a placement complement, a grasp complement).
    Never used to connect nodes (the regular transition does that).
    """

    def __init__(
        self,
        graph: ConstraintGraph,
        base: WaypointEdge,
        leaf_index: int,
        leaf: Sequence[AnyConstraint],
        leaf_state: State,
        weight: float = 10.0,
    ) -> None:
        # The leaf sub-transition and every later one: the waypoints after it (lowering the
        # object onto its surface) would otherwise drift off the copied leaf.
        subs = [e if i < leaf_index else LeafEdge(e, leaf) for i, e in enumerate(base.sub_edges)]
        parents = [e.parent for e in base.sub_edges]
        super().__init__(
            graph, base.name + "_ls", base.from_state, base.to_state, base.containing, subs, weight
        )
        for e, parent in zip(base.sub_edges, parents):
            e.parent = parent  # shared sub-edges stay the regular transition's
        self.base = base
        self.leaf_index = leaf_index
        self.leaf = list(leaf)
        self.leaf_state = leaf_state
        self.reverse_edge = base.reverse_edge
        # Objects whose pose the leaf sets (placement complements): a leaf where they collide
        # with the other objects as they are cannot be reached from there.
        self.leaf_objects = sorted(
            {c.placement.object for c in self.leaf if isinstance(c, PlacementComplement)}
        )

    def generate_target(
        self, q_start: np.ndarray, q: np.ndarray, q_leaf: np.ndarray | None = None
    ) -> ProjectionResult:
        q_prev = q_start
        configs = [q_start]
        result = None
        for e in self.sub_edges:
            q_next = q.copy()
            if isinstance(e, LeafEdge):
                result = e.generate_target(q_prev, q_next, q_leaf)
            else:
                result = e.generate_target(q_prev, q_next)
            if not result:
                return result
            configs.append(q_next)
            q_prev = q_next
        q[:] = q_prev
        self.last_waypoint_configs = configs
        assert result is not None  # __init__ refuses a waypoint edge without sub-edges
        return result


class ConstraintGraph:
    """States and edges of a manipulation problem, with the projection settings they share.

    ``constraints``: graph-wide constraints, in every state and edge (e.g. a humanoid's feet
    on the ground and its centre of mass over them).
    """

    def __init__(
        self,
        problem: ManipulationProblem,
        name: str = "graph",
        constraints: Sequence[AnyConstraint] = (),
        error_threshold: float = 1e-4,
        max_iterations: int = 40,
        line_search: LineSearch = LineSearch(),
        path_step: float = 0.1,
    ) -> None:
        self.problem = problem
        self.path_step = path_step  # progressive projection step of implicit paths (|v| norm)
        self.name = name
        self.constraints = list(constraints)
        self.error_threshold = error_threshold
        self.max_iterations = max_iterations
        self.line_search = line_search
        self.states: dict[str, State] = {}
        self.edges: dict[str, Edge] = {}
        # "cpp": Newton loop in C++ where the constraint kinds allow it; "python": the reference.
        self.projector_backend = "cpp"

    def make_projector(
        self, constraints: Sequence[AnyConstraint], name: str, threshold: float | None = None
    ) -> Projector:
        return Projector(
            self.problem,
            _unique(list(constraints)),
            name=name,
            error_threshold=threshold or self.error_threshold,
            max_iterations=self.max_iterations,
            line_search=self.line_search,
            backend=self.projector_backend,
        )

    def add_state(
        self,
        name: str,
        constraints: Sequence[AnyConstraint],
        waypoint: bool = False,
        priority: int = 0,
        grasps: dict[str, str] | None = None,
    ) -> State:
        if name in self.states:
            raise GraphError(f"state '{name}' already exists")
        s = State(self, name, constraints, waypoint, priority, grasps)
        self.states[name] = s
        return s

    def add_edge(self, edge: Edge) -> Edge:
        if edge.name in self.edges:
            raise GraphError(f"transition '{edge.name}' already exists")
        for s in (edge.from_state, edge.to_state, edge.containing):
            if self.states.get(s.name) is not s:
                raise GraphError(f"{edge.name}: state {s.name} is not in the graph")
        self.edges[edge.name] = edge
        if edge.parent is None:
            edge.from_state.outgoing.append(edge)
        return edge

    def initialize(self) -> None:
        """Compile every projector now (HPP ``graph.initialize()``), not on first use."""
        for s in self.states.values():
            _ = s.projector
        for e in self.edges.values():
            if isinstance(e, WaypointEdge):
                e.common_leaf_projector()
            if isinstance(e, LevelSetEdge):
                for sub in e.sub_edges[e.leaf_index :]:
                    _ = sub.target_projector
            elif not isinstance(e, WaypointEdge):
                _ = e.path_projector, e.target_projector

    def top_edges(self) -> list[Edge]:
        """Transitions between non-waypoint states (not the sub-edges of waypoint edges)."""
        return [e for e in self.edges.values() if e.parent is None]

    def main_states(self) -> list[State]:
        return [s for s in self.states.values() if not s.waypoint]

    def state_of(self, q: np.ndarray) -> State | None:
        """The most constrained (highest priority) non-waypoint state containing q."""
        for s in sorted(self.main_states(), key=lambda s: -s.priority):
            if s.contains(q):
                return s
        return None

    def edges_between(self, a: State, b: State) -> list[Edge]:
        """Transitions from a to b that connect configurations (level-set twins excluded: they
        build the same paths as their regular transition)."""
        return [e for e in a.outgoing if e.to_state is b and not isinstance(e, LevelSetEdge)]

    # ------------------------------------------------------------------------------ export
    def to_dot(self) -> str:
        """Graphviz description: states as ellipses, waypoint states as dashed hexagons."""
        rankdir = "LR" if len(self.main_states()) <= 4 else "TB"  # wide graphs read downwards
        lines = [
            f'digraph "{self.name}" {{',
            f"  rankdir={rankdir};",
            "  node [fontsize=10];",
            "  edge [fontsize=8];",
        ]
        ids = {name: f"s{i}" for i, name in enumerate(self.states)}
        for name, s in self.states.items():
            shape = "shape=hexagon, style=dashed" if s.waypoint else "shape=ellipse"
            lines.append(f'  {ids[name]} [label="{_esc(name)}", {shape}];')
        for e in self.edges.values():
            if isinstance(e, WaypointEdge):
                continue
            style = ", style=dashed" if e.weight == 0 and e.parent is None else ""
            lines.append(
                f"  {ids[e.from_state.name]} -> {ids[e.to_state.name]} "
                f'[label="{_esc(e.name)}"{style}];'
            )
        lines.append("}")
        return "\n".join(lines) + "\n"

    def write_picture(self, path: str | Path) -> Path:
        """Write the graph as a picture (format from the suffix: .png, .svg, .pdf; .dot = text)."""
        path = Path(path)
        dot = self.to_dot()
        if path.suffix == ".dot":
            path.write_text(dot)
            return path
        fmt = path.suffix.lstrip(".") or "png"
        try:
            subprocess.run(
                ["dot", f"-T{fmt}", "-o", str(path)],
                input=dot.encode(),
                check=True,
                capture_output=True,
                timeout=60,
            )
        except FileNotFoundError as e:
            raise GraphError("graphviz 'dot' not found (Debian package graphviz)") from e
        except subprocess.CalledProcessError as e:
            raise GraphError(f"dot failed: {e.stderr.decode(errors='replace')}") from e
        return path

    def describe(self) -> dict:
        """Names, constraints and structure (for the plan file)."""
        catalog: dict[str, dict] = {}
        model = self.problem.model
        for c in (
            self.constraints
            + [c for s in self.states.values() for c in s.constraints]
            + [c for e in self.edges.values() for c in e.constraints]
        ):
            if c.name not in catalog:
                catalog[c.name] = c.to_dict(model)
        return {
            "constraint_definitions": catalog,
            "name": self.name,
            "error_threshold": self.error_threshold,
            "graph_constraints": [c.name for c in self.constraints],
            "states": [
                {
                    "name": s.name,
                    "waypoint": s.waypoint,
                    "priority": s.priority,
                    "grasps": s.grasps,
                    "constraints": [c.name for c in s.constraints],
                }
                for s in self.states.values()
            ],
            "transitions": [
                {
                    "name": e.name,
                    "from": e.from_state.name,
                    "to": e.to_state.name,
                    "containing_state": e.containing.name,
                    "weight": e.weight,
                    "constraints": [c.name for c in e.constraints],
                    "waypoint_edges": [x.name for x in e.sub_edges]
                    if isinstance(e, WaypointEdge)
                    else [],
                    "level_set": isinstance(e, LevelSetEdge),
                }
                for e in self.edges.values()
            ],
        }


def _esc(s: str) -> str:
    return s.replace('"', '\\"')


def _unique(items: list) -> list:
    seen: set[int] = set()
    out = []
    for c in items:
        if id(c) not in seen:
            seen.add(id(c))
            out.append(c)
    return out
