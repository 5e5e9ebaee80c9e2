"""Checks of a planning query before planning: each failure is one line naming what fails.

* :func:`nearest_state` -- a configuration in no state of the graph: the state it comes closest
  to and the constraint of that state it violates most (with the error and the threshold);
* :func:`collision_message` -- a configuration in collision: the colliding pairs by name;
* :func:`check_reachable` -- an object whose goal (or start) pose no grasp of the graph can
  reach: the object, the pose and the grasps tried (every pick-and-place goes through a grasp of
  the object where it is put down or picked up).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from marionette.planning.collision import CollisionChecker
from marionette.planning.constraints import (
    Constraint,
    ExplicitRelativePose,
    Kinematics,
    LockedJoint,
    Placement,
)
from marionette.planning.graph import ConstraintGraph, State
from marionette.planning.problem import ManipulationProblem, sample_configuration


class PlanningError(RuntimeError):
    """A query that cannot be planned (start/goal in no state, in collision, out of reach)."""


def constraint_error(c, kin: Kinematics, q: np.ndarray) -> float:
    """How far q is from satisfying one constraint (``kin`` updated at q)."""
    if isinstance(c, LockedJoint):
        return c.error(q)
    if isinstance(c, ExplicitRelativePose):
        X = pin.XYZQUATToSE3(q[c.idx_q : c.idx_q + 7])
        return float(np.linalg.norm(pin.log6(c.pose(kin).actInv(X)).vector))
    if isinstance(c, Placement):
        c.select_pair(kin)
    if isinstance(c, Constraint):
        return float(np.linalg.norm(c.compute_error(kin)))
    raise TypeError(f"not a constraint: {c!r}")


def nearest_state(graph: ConstraintGraph, q: np.ndarray) -> tuple[State, str, float]:
    """(state, constraint name, error): the main state whose most violated constraint is the
    least violated, and that constraint."""
    kin = Kinematics(graph.problem.model)
    kin.update(q, jacobians=False)
    best = None
    for s in graph.main_states():
        worst = max(
            ((c.name, constraint_error(c, kin, q)) for c in graph.constraints + s.constraints),
            key=lambda t: t[1],
            default=("", 0.0),
        )
        if best is None or worst[1] < best[2]:
            best = (s, *worst)
    assert best is not None
    return best


def no_state_message(graph: ConstraintGraph, q: np.ndarray, what: str) -> str:
    state, name, err = nearest_state(graph, q)
    return (
        f"{what} configuration is in no state of the graph: the nearest, '{state.name}', "
        f"needs '{name}' (error {err:.3g} > threshold {graph.error_threshold:g})"
    )


def collision_message(checker: CollisionChecker, q: np.ndarray, what: str) -> str:
    pairs = checker.colliding_pairs(q)
    shown = ", ".join(f"{a} - {b}" for a, b in pairs[:3])
    more = f" (and {len(pairs) - 3} more pairs)" if len(pairs) > 3 else ""
    return f"{what} configuration is in collision: {shown}{more}"


def check_reachable(
    problem: ManipulationProblem,
    graph: ConstraintGraph,
    checker: CollisionChecker,
    q_from: np.ndarray,
    q_to: np.ndarray,
    attempts: int = 200,
    seed: int = 0,
) -> None:
    """Raise :class:`PlanningError` when an object that moves between q_from and q_to cannot be
    held, by any grasp of the graph, where it is picked up or put down (the object locked there,
    the robots projected from ``attempts`` random configurations, each result checked for
    collisions); nothing to check for objects that stay."""
    rng = np.random.default_rng(seed)
    for name, info in problem.objects.items():
        sl = slice(info.idx_q, info.idx_q + 7)
        a, b = pin.XYZQUATToSE3(q_from[sl]), pin.XYZQUATToSE3(q_to[sl])
        if np.linalg.norm(pin.log6(a.actInv(b)).vector) <= graph.error_threshold:
            continue
        holding = [
            s
            for s in graph.main_states()
            if any(problem.handles[h].object == name for h in s.grasps.values())
        ]
        if not holding:
            raise PlanningError(
                f"{name} must move but no state of the graph grasps it (check graph.objects and "
                f"the rules)"
            )
        for where, q_ref in (("goal", q_to), ("start", q_from)):
            if not _holdable(problem, graph, checker, holding, q_ref, info, attempts, rng):
                grasps = sorted({f"{g} > {h}" for s in holding for g, h in s.grasps.items()})
                raise PlanningError(
                    f"{name} cannot be grasped at its {where} pose "
                    f"{np.round(q_ref[info.idx_q : info.idx_q + 3], 3).tolist()}: "
                    f"no collision-free "
                    f"configuration of {', '.join(grasps)} there in {attempts} attempts "
                    f"(out of reach or blocked)"
                )


def _holdable(problem, graph, checker, states, q_ref, info, attempts, rng) -> bool:
    value = q_ref[info.idx_q : info.idx_q + 7].copy()
    for state in states:
        lock = LockedJoint(f"{info.name} held there", problem.model, info.joint_id, value)
        lock.parametrised = False
        projector = graph.make_projector(
            graph.constraints + state.constraints + [lock], f"reach {state.name}"
        )
        projector.set_rhs_from(q_ref)
        lock.value = value
        allowed = checker.grasp_contact_pairs(state.grasps)
        for k in range(attempts // len(states)):
            q = q_ref.copy() if k == 0 else sample_configuration(problem, rng)
            # the other objects stay where they are in the query
            for o in problem.objects.values():
                if o.name != info.name:
                    q[o.idx_q : o.idx_q + 7] = q_ref[o.idx_q : o.idx_q + 7]
            if projector.project(q) and checker.is_valid(q, allowed):
                return True
    return False
