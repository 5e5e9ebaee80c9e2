"""HPP 9.0.2 side of the UR5 box benchmark: the problem of problem.yaml built in pyhpp.

Runs inside the benchmark venv (.venv-bench, never the product's): ``python hpp_side.py
--seeds 1 50 --out result.json``.  Same frames, bounds, contacts, start and goal as
../../shared/bench/ur5_box/problem.json: ConstraintGraphFactory + ManipulationPlanner,
Straight steering, Dichotomy(0) path validation, Progressive(0.01) path projector, error
threshold 1e-4, 40 iterations.  Writes per-seed success and planning time, and the median
projection time of each state from uniform random configurations.
"""

from __future__ import annotations

import argparse
import json
import time
from math import pi
from pathlib import Path

import numpy as np
import pinocchio
from pinocchio import SE3
from pyhpp.core import Dichotomy, Straight
from pyhpp.manipulation import (
    Device,
    Graph,
    ManipulationPlanner,
    Problem,
    ProgressiveProjector,
    urdf,
)
from pyhpp.manipulation.constraint_graph_factory import ConstraintGraphFactory

HERE = Path(__file__).resolve().parent
UR5 = "package://example-robot-data/robots/ur_description/"
Q_INIT = [0.0, -pi / 2, pi / 2, -pi / 2, -pi / 2, 0.0, 0.5, -0.25, 0.0251, 0, 0, 0, 1]
Q_GOAL = [0.0, -pi / 2, pi / 2, -pi / 2, -pi / 2, 0.0, 0.5, 0.25, 0.0251, 0, 0, 0, 1]
JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]


def build():
    robot = Device("ur5-box")
    urdf.loadModel(
        robot,
        0,
        "ur5",
        "anchor",
        UR5 + "urdf/ur5_gripper.urdf",
        UR5 + "srdf/ur5_gripper.srdf",
        SE3.Identity(),
    )
    urdf.loadModel(
        robot, 0, "box", "freeflyer", str(HERE / "box.urdf"), str(HERE / "box.srdf"), SE3.Identity()
    )
    urdf.loadModel(
        robot,
        0,
        "table",
        "anchor",
        str(HERE / "table.urdf"),
        str(HERE / "table.srdf"),
        SE3.Identity(),
    )
    for j in JOINTS:
        robot.setJointBounds(f"ur5/{j}", [-3.14159265, 3.14159265])
    robot.setJointBounds(
        "box/root_joint",
        [
            0.2,
            0.9,
            -0.6,
            0.6,
            -0.1,
            1.0,
            -1.0001,
            1.0001,
            -1.0001,
            1.0001,
            -1.0001,
            1.0001,
            -1.0001,
            1.0001,
        ],
    )
    problem = Problem(robot)
    graph = Graph("graph", robot, problem)
    graph.maxIterations(40)
    graph.errorThreshold(1e-4)
    factory = ConstraintGraphFactory(graph)
    factory.setGrippers(["ur5/gripper"])
    factory.setObjects(["box"], [["box/handle"]], [["box/bottom"]])
    factory.environmentContacts(["table/top"])
    factory.generate()
    problem.steeringMethod = Straight(problem)
    problem.pathValidation = Dichotomy(robot, 0)
    problem.pathProjector = ProgressiveProjector(problem.distance(), problem.steeringMethod, 0.01)
    graph.initialize()
    problem.initConfig(np.array(Q_INIT))
    problem.addGoalConfig(np.array(Q_GOAL))
    problem.constraintGraph(graph)
    return robot, problem, graph


def plan(problem, seed: int) -> tuple[bool, float, int]:
    pinocchio.seed(seed)
    np.random.seed(seed)
    planner = ManipulationPlanner(problem)
    planner.maxIterations(5000)
    planner.timeOut(30.0)
    t0 = time.perf_counter()
    try:
        planner.solve()
        ok = True
    except Exception:  # HPP raises when the iteration limit is reached
        ok = False
    dt = time.perf_counter() - t0
    nodes = len(planner.roadmap().nodes()) if hasattr(planner.roadmap(), "nodes") else -1
    return ok, dt, nodes


def projection_times(robot, graph, samples: int, rng: np.random.Generator) -> dict:
    lo = np.array([-3.14159265] * 6 + [0.2, -0.6, -0.1])
    hi = np.array([3.14159265] * 6 + [0.9, 0.6, 1.0])
    out = {}
    for name in graph.getStateNames():
        state = graph.getState(name)
        times, ok = [], 0
        for _ in range(samples):
            q = np.zeros(13)
            q[:9] = lo + rng.random(9) * (hi - lo)
            u = rng.random(3)
            a, b = np.sqrt(1 - u[0]), np.sqrt(u[0])
            q[9:] = [
                a * np.sin(2 * pi * u[1]),
                a * np.cos(2 * pi * u[1]),
                b * np.sin(2 * pi * u[2]),
                b * np.cos(2 * pi * u[2]),
            ]
            t0 = time.perf_counter()
            success, _, _ = graph.applyStateConstraints(state, q)
            times.append(time.perf_counter() - t0)
            ok += bool(success)
        out[name] = {"median_us": float(np.median(times) * 1e6), "success": ok / samples}
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs=2, default=[1, 50], metavar=("FIRST", "LAST"))
    ap.add_argument("--projection-samples", type=int, default=200)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    robot, problem, graph = build()
    runs = []
    for s in range(args.seeds[0], args.seeds[1] + 1):
        ok, dt, nodes = plan(problem, s)
        runs.append({"seed": s, "success": ok, "time_s": dt, "nodes": nodes})
    proj = projection_times(robot, graph, args.projection_samples, np.random.default_rng(0))
    args.out.write_text(
        json.dumps({"system": "HPP 9.0.2", "runs": runs, "projections": proj}, indent=1)
    )


if __name__ == "__main__":
    main()
