"""User waypoints that guide Manipulation-RRT (thesis §3.4.2: "the user also provides some
waypoint states to guide the motion planner and decrease the planning time").

A guide entry names a graph state and the poses of (some) objects; :func:`guide_configuration`
turns it into a collision-free configuration of that state (objects held at those poses, the
robot solved by projection from perturbations of a reference configuration), and
:func:`plan_through` plans init -> guide 1 -> ... -> goal, one Manipulation-RRT query per leg.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin

from marionette.planning.collision import CollisionChecker
from marionette.planning.constraints import LockedJoint
from marionette.planning.graph import AnyConstraint, ConstraintGraph, State
from marionette.planning.planner import ManipulationRRT, PlanResult
from marionette.planning.problem import ManipulationProblem, _pose7
from marionette.planning.query import PlanningError, no_state_message

if TYPE_CHECKING:
    from marionette.planning.path import ConstrainedPath


def guide_configuration(
    problem: ManipulationProblem,
    graph: ConstraintGraph,
    checker: CollisionChecker,
    entry: dict[str, Any],
    q_ref: np.ndarray,
    rng: np.random.Generator,
    attempts: int = 300,
) -> np.ndarray:
    """Collision-free configuration of ``entry['state']`` with the listed objects at their
    poses; raises :class:`PlanningError` naming the state when none is found."""
    name = entry.get("state")
    if name not in graph.states:
        raise PlanningError(f"guide: unknown state {name!r}")
    state = graph.states[name]
    locks: list[AnyConstraint] = []
    q0 = np.asarray(q_ref, dtype=float).copy()
    for obj, pose in entry.items():
        if obj == "state":
            continue
        if obj not in problem.objects:
            raise PlanningError(f"guide: {obj!r} is neither 'state' nor an object")
        info = problem.objects[obj]
        value = pin.SE3ToXYZQUAT(_pose7(pose, f"guide.{obj}"))
        q0[info.idx_q : info.idx_q + 7] = value
        lock = LockedJoint(f"guide {obj}", problem.model, info.joint_id, value)
        lock.parametrised = False
        locks.append(lock)
    projector = graph.make_projector(graph.constraints + state.constraints + locks, f"guide {name}")
    allowed = checker.grasp_contact_pairs(state.grasps)
    free = projector.free
    for k in range(attempts):
        q = q0.copy()
        if k > 0:  # perturb the free variables more and more
            dv = np.zeros(problem.nv)
            dv[free] = rng.normal(scale=min(0.05 * k, 1.0), size=int(free.sum()))
            q = pin.integrate(problem.model, q, dv)
            q = np.clip(q, problem.lower, problem.upper)  # every bound is finite
            for i in problem.freeflyer_idx_q:
                q[i + 3 : i + 7] /= np.linalg.norm(q[i + 3 : i + 7])
        if projector.project(q) and state.contains(q) and checker.is_valid(q, allowed):
            return q
    raise PlanningError(
        f"guide: no collision-free configuration of {name!r} in {attempts} attempts"
    )


def leg_states(graph: ConstraintGraph, q_a: np.ndarray, q_b: np.ndarray) -> set[State]:
    """States of the shortest transition sequences from q_a's state to q_b's (breadth first
    over the transitions between main states): the states a leg between two waypoints goes
    through -- the leg's planner extends along no other transition."""
    a, b = graph.state_of(q_a), graph.state_of(q_b)
    if a is None:
        raise PlanningError(no_state_message(graph, q_a, "leg start"))
    if b is None:
        raise PlanningError(no_state_message(graph, q_b, "leg end"))
    dist_a, dist_b = _distances(graph, a, forward=True), _distances(graph, b, forward=False)
    if b not in dist_a:
        raise PlanningError(f"guide: no sequence of transitions from '{a.name}' to '{b.name}'")
    total = dist_a[b]
    return {s for s in dist_a if s in dist_b and dist_a[s] + dist_b[s] == total}


def _distances(graph: ConstraintGraph, start: State, forward: bool) -> dict[State, int]:
    edges = [e for e in graph.top_edges() if e.from_state is not e.to_state]
    dist = {start: 0}
    frontier = [start]
    while frontier:
        nxt = []
        for s in frontier:
            for e in edges:
                src, dst = (e.from_state, e.to_state) if forward else (e.to_state, e.from_state)
                if src is s and dst not in dist:
                    dist[dst] = dist[s] + 1
                    nxt.append(dst)
        frontier = nxt
    return dist


def plan_through(
    problem: ManipulationProblem,
    graph: ConstraintGraph,
    checker: CollisionChecker,
    configurations: Sequence[np.ndarray],
    seed: int = 0,
    max_iterations: int = 5000,
    timeout_s: float = 600.0,
    progress: Callable[[int, int, int], None] | None = None,
) -> PlanResult:
    """Plan configurations[0] -> [1] -> ... -> [-1], one query per leg, paths concatenated;
    each leg extends only along the transitions of its shortest state sequences
    (:func:`leg_states`)."""
    t0 = time.perf_counter()
    paths: list[ConstrainedPath] = []
    stats: dict[str, int] = {}
    iterations, nodes = 0, 0
    for leg, (a, b) in enumerate(zip(configurations, configurations[1:])):
        left = timeout_s - (time.perf_counter() - t0)
        planner = ManipulationRRT(
            problem, graph, checker, seed=seed + 1000 * leg, states=leg_states(graph, a, b)
        )
        r = planner.solve(a, [b], max_iterations, max(left, 0.0), progress)
        iterations += r.iterations
        nodes += r.nodes
        for k, v in r.statistics.items():
            stats[k] = stats.get(k, 0) + v
        if not r.success:
            return PlanResult(
                False,
                paths,
                iterations,
                time.perf_counter() - t0,
                nodes,
                f"leg {leg + 1}/{len(configurations) - 1}: {r.reason}",
                stats,
            )
        paths += r.paths
    return PlanResult(True, paths, iterations, time.perf_counter() - t0, nodes, "", stats)
