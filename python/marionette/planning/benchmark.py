"""Planning benchmark: success rate, planning time and projection time per state, per seed.

Library side of ``bench/ur5_box_vs_hpp`` (the script only runs this and the HPP peer and
prints both): the same figures HPP's side reports, measured the same way.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from marionette.planning.collision import CollisionChecker
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.planner import ManipulationRRT
from marionette.planning.problem import ManipulationProblem, load_problem, random_configuration


@dataclasses.dataclass
class Run:
    seed: int
    success: bool
    time_s: float
    nodes: int


def plan_seeds(
    problem: ManipulationProblem,
    seeds: Sequence[int],
    max_iterations: int = 5000,
    timeout_s: float = 30.0,
) -> list[Run]:
    """One planning query per seed: a fresh roadmap each time, the graph (initialised before
    timing, as HPP's) and the collision checker shared."""
    checker = CollisionChecker(problem)
    graph = graph_from_settings(problem)
    graph.initialize()
    runs = []
    for s in seeds:
        planner = ManipulationRRT(problem, graph, checker, seed=s)
        t0 = time.perf_counter()
        res = planner.solve(problem.q_init, [problem.q_goal], max_iterations, timeout_s)
        runs.append(Run(s, res.success, time.perf_counter() - t0, res.nodes))
    return runs


def projection_times(
    problem: ManipulationProblem, samples: int = 200, seed: int = 0
) -> dict[str, dict[str, float]]:
    """Median time and success rate of projecting uniform samples onto each state."""
    graph = graph_from_settings(problem)
    rng = np.random.default_rng(seed)
    out = {}
    for name, state in graph.states.items():
        times, ok = [], 0
        state.projector.set_rhs_from(problem.q_init)
        for _ in range(samples):
            q = random_configuration(problem, rng)
            t0 = time.perf_counter()
            r = state.project(q)
            times.append(time.perf_counter() - t0)
            ok += r.success
        out[name] = {"median_us": float(np.median(times) * 1e6), "success": ok / samples}
    return out


def summary(runs: Sequence[Run] | Sequence[dict]) -> dict[str, float]:
    """success rate, median / p90 planning time [ms] over successes and all runs."""
    rows = [dataclasses.asdict(r) if isinstance(r, Run) else r for r in runs]
    t = np.array([r["time_s"] for r in rows]) * 1e3
    ok = np.array([r["success"] for r in rows], dtype=bool)
    return {
        "runs": len(rows),
        "success_rate": float(ok.mean()) if len(rows) else 0.0,
        "median_ms": float(np.median(t)) if len(t) else float("nan"),
        "p90_ms": float(np.percentile(t, 90)) if len(t) else float("nan"),
        "median_nodes": float(np.median([r["nodes"] for r in rows])) if rows else float("nan"),
    }


def run_marionette(problem_file: Path, seeds: Sequence[int], samples: int) -> dict:
    problem = load_problem(problem_file)
    runs = plan_seeds(problem, seeds)
    return {
        "system": "marionette",
        "runs": [dataclasses.asdict(r) for r in runs],
        "projections": projection_times(problem, samples),
    }
