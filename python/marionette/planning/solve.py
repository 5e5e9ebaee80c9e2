"""From a problem to an executable plan in one call: what ``marionette plan`` and the demos run.

:func:`plan_problem` plans with Manipulation-RRT (leg by leg through the problem's guide
waypoints when it has some, thesis §3.4.2), then shortens the result with the optimisation that
keeps transition semantics (``optimize.py``, on by default).  :func:`planner_fingerprint`
identifies the planner's code, for caches of plans.
"""

from __future__ import annotations

import dataclasses
import hashlib
import time
from collections.abc import Callable
from functools import cache
from pathlib import Path

import numpy as np

from marionette.planning.collision import CollisionChecker
from marionette.planning.graph import ConstraintGraph
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.guide import guide_configuration, plan_through
from marionette.planning.optimize import optimize_paths
from marionette.planning.path import ConstrainedPath
from marionette.planning.planner import ManipulationRRT, PlanResult
from marionette.planning.problem import ManipulationProblem
from marionette.planning.query import (
    PlanningError,
    check_reachable,
    collision_message,
    no_state_message,
)
from marionette.planning.timing import Limits


@dataclasses.dataclass
class Solution:
    """``result``: the planner's outcome (raw paths); ``paths``: the optimised plan (the raw one
    when optimisation is off or planning failed); ``limits``: velocity and acceleration limits
    for timing it (plan files, :func:`marionette.planning.timing.time_parameterize`)."""

    result: PlanResult
    paths: list[ConstrainedPath]
    graph: ConstraintGraph
    checker: CollisionChecker
    limits: Limits
    optimize_s: float = 0.0

    @property
    def success(self) -> bool:
        return self.result.success

    @property
    def length(self) -> float:
        return float(sum(p.length for p in self.paths))


def plan_problem(
    problem: ManipulationProblem,
    seed: int = 0,
    max_iterations: int | None = None,
    timeout_s: float | None = None,
    optimize_iterations: int = 60,
    progress: Callable[[int, int, int], None] | None = None,
    graph: ConstraintGraph | None = None,
    checker: CollisionChecker | None = None,
) -> Solution:
    """Plan ``problem`` from its init to its goal (see the module docstring).  Iteration and time
    limits default to the problem file's ``planner:`` section; ``optimize_iterations`` = 0 keeps
    the raw plan.  Raises :class:`marionette.planning.query.PlanningError` (one line) on a start
    or goal in no state or in collision, an object that cannot be grasped where it is picked up
    or put down, or a guide waypoint that cannot be built."""
    settings = problem.settings.get("planner", {})
    max_it = max_iterations or int(settings.get("max_iterations", 5000))
    timeout = timeout_s or float(settings.get("timeout_s", 60.0))
    q_init, q_goal = problem.q_init, problem.q_goal
    if q_init is None or q_goal is None:
        raise PlanningError(f"problem '{problem.name}' needs 'init' and 'goal' configurations")
    graph = graph or graph_from_settings(problem)
    checker = checker or CollisionChecker(problem)
    for q, what in ((q_init, "initial"), (q_goal, "goal")):
        state = graph.state_of(q)
        if state is None:
            raise PlanningError(no_state_message(graph, q, what))
        if not checker.is_valid(q, checker.grasp_contact_pairs(state.grasps)):
            raise PlanningError(collision_message(checker, q, what))
    check_reachable(problem, graph, checker, q_init, q_goal)
    if problem.settings.get("guide"):
        rng = np.random.default_rng(seed)
        waypoints = [
            guide_configuration(problem, graph, checker, entry, q_init, rng)
            for entry in problem.settings["guide"]
        ]
        result = plan_through(
            problem,
            graph,
            checker,
            [q_init, *waypoints, q_goal],
            seed,
            max_it,
            timeout,
            progress,
        )
    else:
        planner = ManipulationRRT(problem, graph, checker, seed=seed)
        result = planner.solve(q_init, [q_goal], max_it, timeout, progress)
    limits = Limits.of_robots(
        problem,
        acceleration=float(settings.get("acceleration_limit", 2.0)),
        velocity_scale=float(settings.get("velocity_scale", 1.0)),
    )
    paths = result.paths
    t0 = time.perf_counter()
    if result.success and optimize_iterations > 0:
        paths = optimize_paths(
            paths, graph, checker, np.random.default_rng(seed), optimize_iterations
        )
    return Solution(result, paths, graph, checker, limits, time.perf_counter() - t0)


@cache
def planner_fingerprint() -> str:
    """SHA-256 of the planning package's Python sources and of the compiled extension: a plan
    cached under another fingerprint was made by other planner code."""
    h = hashlib.sha256()
    here = Path(__file__).parent
    for f in sorted(here.glob("*.py")):
        h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    from marionette import _core

    h.update(Path(_core.__file__).read_bytes())
    return h.hexdigest()
