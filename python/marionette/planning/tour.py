"""The order to visit targets in: an open travelling-salesman path from a fixed start (the
"travelling salesman solver" Agimus adds for its deburring demonstration, thesis 000 §5.3.3).

OR-tools' routing solver does the search (first solution by path cheapest arc, then guided
local search for ``time_limit_s``); the start is its depot and the end is free: a dummy node
that every target reaches at no cost closes the route. :func:`brute_force_order` is the exact
reference for small instances (tests).
"""

from __future__ import annotations

import itertools

import numpy as np

_SCALE = 1e6  # OR-tools costs are integers: costs in micro-units


def path_cost(costs: np.ndarray, order: list[int], start: int = 0) -> float:
    """Cost of visiting ``order`` from ``start`` (no return)."""
    nodes = [start, *order]
    return float(sum(costs[a, b] for a, b in zip(nodes, nodes[1:])))


def tsp_order(costs: np.ndarray, start: int = 0, time_limit_s: float = 1.0) -> list[int]:
    """Indices of every node but ``start``, in the order of the cheapest open path from
    ``start`` that OR-tools finds (``costs``: n x n, finite, >= 0; need not be symmetric)."""
    from ortools.constraint_solver import pywrapcp, routing_enums_pb2

    c = np.asarray(costs, dtype=float)
    n = c.shape[0]
    if c.shape != (n, n) or not np.all(np.isfinite(c)) or np.any(c < 0):
        raise ValueError(
            f"costs must be a square matrix of finite values >= 0, got shape {c.shape}"
        )
    if not 0 <= start < n:
        raise ValueError(f"start {start} is not a node of {n}")
    if n <= 2:
        return [i for i in range(n) if i != start]
    # node n: the free end (reached from anywhere at no cost, never left)
    m = np.zeros((n + 1, n + 1))
    m[:n, :n] = c
    m[n, :] = 0.0
    integer = np.rint(m * _SCALE).astype(np.int64)
    manager = pywrapcp.RoutingIndexManager(n + 1, 1, [start], [n])
    routing = pywrapcp.RoutingModel(manager)

    def arc(i: int, j: int) -> int:
        return int(integer[manager.IndexToNode(i), manager.IndexToNode(j)])

    routing.SetArcCostEvaluatorOfAllVehicles(routing.RegisterTransitCallback(arc))
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = routing_enums_pb2.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = (
        routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH
    )
    params.time_limit.FromMilliseconds(max(1, int(time_limit_s * 1000)))
    solution = routing.SolveWithParameters(params)
    if solution is None:
        raise RuntimeError("OR-tools found no route (it always should on a complete graph)")
    order, i = [], routing.Start(0)
    while not routing.IsEnd(i):
        node = manager.IndexToNode(i)
        if node != start:
            order.append(node)
        i = solution.Value(routing.NextVar(i))
    return order


def brute_force_order(costs: np.ndarray, start: int = 0) -> list[int]:
    """The exact cheapest open path from ``start`` by enumeration (n <= 9)."""
    n = costs.shape[0]
    if n > 9:
        raise ValueError(f"{n} nodes: too many to enumerate")
    rest = [i for i in range(n) if i != start]
    return list(min(itertools.permutations(rest), key=lambda p: path_cost(costs, list(p), start)))
