"""HPP 9.0.2 side of the planning benchmarks: any problem exported by
``marionette.planning.hpp_export`` built in pyhpp and planned seed by seed.

Runs inside the benchmark venv (.venv-bench, never the product's):
``python hpp_side.py problem.json --seeds 1 20 --out result.json [--optimize]``.
ConstraintGraphFactory + ManipulationPlanner, Straight steering, Dichotomy(0) path validation,
Progressive(0.01) path projector, the problem's error threshold, HPP's default 40 projection
iterations.  Graph constraints (fixed frames, centre of mass, locked joints) are added to every
state with marionette's values at init, except the centre of mass: HPP's is another function
than Pinocchio's, so it keeps HPP's own value at init.  A guided problem is planned leg by leg
(one planner per leg, same roadmap settings), its waypoints projected onto HPP's constraints.
With ``--optimize``, the solution goes through HPP's manipulation RandomShortcut
(transition-aware) and its arm path length is measured the way marionette's is.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pinocchio
from pinocchio import XYZQUATToSE3
from pyhpp.constraints import (
    ComparisonType,
    ComparisonTypes,
    Implicit,
    LockedJoint,
    Transformation,
)
from pyhpp.core import Dichotomy, Straight
from pyhpp.manipulation import (
    Device,
    Graph,
    ManipulationPlanner,
    Problem,
    ProgressiveProjector,
    RandomShortcut,
    urdf,
)
from pyhpp.manipulation.constraint_graph_factory import (
    ConstraintFactory,
    ConstraintGraphFactory,
    Rule,
)
from pyhpp.pinocchio import LiegroupElement


class OwnSurfacesExcluded(ConstraintFactory):
    """HPP's factory offers every environment contact to every object, its own surfaces
    included: a box whose top face is an environment contact (a tower) would be placed on
    itself, an explicit constraint whose input contains its output, which HPP refuses. An
    object is placed on the surfaces of the others only, as marionette's graph does."""

    def buildPlacement(self, o):
        factory = self.graphfactory
        every = factory.envContacts
        factory.envContacts = tuple(c for c in every if not c.startswith(o + "/"))
        try:
            return super().buildPlacement(o)
        finally:
            factory.envContacts = every


def build(spec: dict):
    robot = Device(spec["name"])
    for m in spec["models"]:
        urdf.loadModelFromString(
            robot, 0, m["name"], m["root"], m["urdf"], m["srdf"], XYZQUATToSE3(np.array(m["pose"]))
        )
    for joint, bounds in spec["joint_bounds"].items():
        robot.setJointBounds(joint, bounds)
    if robot.configSize() != spec["nq"]:
        raise RuntimeError(
            f"HPP has {robot.configSize()} configuration entries, marionette {spec['nq']}"
        )
    problem = Problem(robot)
    graph = Graph("graph", robot, problem)
    g = spec["graph"]
    graph.maxIterations(40)
    graph.errorThreshold(g["error_threshold"])
    factory = ConstraintGraphFactory(graph)
    factory.constraints = OwnSurfacesExcluded(factory, graph)
    factory.setGrippers(g["grippers"])
    factory.setObjects(
        [o[0] for o in g["objects"]], [o[1] for o in g["objects"]], [o[2] for o in g["objects"]]
    )
    factory.environmentContacts(g["environment_contacts"])
    if g["rules"]:
        factory.setRules([Rule(gr, h, link) for gr, h, link in g["rules"]])
    for o in g["objects"]:
        factory.setPreplacementDistance(o[0], g["preplacement_distance"])
    factory.generate()
    constraints = graph_constraints(robot, problem, g["constraints"], spec["legs"][0][0])
    if constraints:
        graph.addNumericalConstraintsToGraph(constraints)
    for name, w in g["weights"].items():
        graph.setWeight(graph.getTransition(name), round(w))
    problem.steeringMethod = Straight(problem)
    problem.pathValidation = Dichotomy(robot, 0)
    problem.pathProjector = ProgressiveProjector(problem.distance(), problem.steeringMethod, 0.01)
    graph.initialize()
    problem.constraintGraph(graph)
    return robot, problem, graph


def graph_constraints(robot, problem, entries: list[dict], q_init) -> list:
    """HPP constraints of marionette's graph constraints (values taken at marionette's init
    ``q_init``). HPP's RelativeCom is in a joint frame: the first fixed frame's joint (a foot,
    which the other constraints keep still)."""
    out = []
    model = robot.model()
    fixed = [e for e in entries if e["type"] == "fixed_frame"]
    for e in entries:
        if e["type"] == "locked_joint":
            out.append(LockedJoint(robot, e["joint"], np.array(e["value"])))
        elif e["type"] == "fixed_frame":
            jid = model.getJointId(e["joint"])
            M_JF = XYZQUATToSE3(np.array(e["M_JF"]))
            X_WF = XYZQUATToSE3(np.array(e["X_WF"]))
            f = Transformation(
                f"{e['joint']} fixed", robot, jid, M_JF, X_WF, [bool(v) for v in e["mask"]]
            )
            comparison = ComparisonTypes()
            comparison.extend([ComparisonType.EqualToZero] * sum(e["mask"]))
            active = pinocchio.StdVec_Bool()
            active.extend([True] * sum(e["mask"]))
            out.append(Implicit(f, comparison, active))
        elif e["type"] == "com":
            if not fixed:
                raise ValueError("a centre-of-mass constraint needs a fixed frame to refer to")
            # HPP's centre of mass is not Pinocchio's (TALOS at init: 0.645 m high in HPP 9.0.2,
            # 0.877 m in Pinocchio, same masses), so the reference is HPP's own value at init
            # in the foot's joint frame: HPP keeps its centre of mass where it starts, as
            # marionette keeps its own.
            joint = fixed[0]["joint"]
            probe = problem.createRelativeComConstraint(
                "com at init", "", joint, np.zeros(3), [True] * 3
            )
            value = LiegroupElement(probe.function().outputSpace())
            probe.function().value(value, np.asarray(q_init, dtype=float))
            out.append(
                problem.createRelativeComConstraint(
                    "com", "", joint, np.array(value.vector()), [bool(v) for v in e["mask"]]
                )
            )
        else:
            raise ValueError(f"unknown graph constraint {e['type']}")
    return out


def arm_length(path, arm: list[int], step: float = 0.01) -> float:
    """Sum of |delta q_arm| over samples every ``step`` of the path parameter."""
    tr = path.timeRange()
    t0, t1 = tr.first, tr.second
    n = max(1, int(np.ceil((t1 - t0) / step)))
    qs = np.array([path.eval(t0 + (t1 - t0) * k / n)[0] for k in range(n + 1)])[:, arm]
    return float(np.linalg.norm(np.diff(qs, axis=0), axis=1).sum())


def hpp_legs(graph, legs: list, waypoint_states: list[str]) -> list:
    """The legs with each waypoint projected onto HPP's own constraints of its state (HPP's
    centre of mass is not marionette's: a waypoint that balances marionette's is up to 6 cm
    off HPP's); the next leg starts from the projected waypoint. Raises when HPP cannot
    project one."""
    out, start = [], np.asarray(legs[0][0], dtype=float)
    for k, (_, goal) in enumerate(legs):
        goal = np.asarray(goal, dtype=float)
        if k < len(waypoint_states):
            ok, goal, error = graph.applyStateConstraints(graph.getState(waypoint_states[k]), goal)
            if not ok:
                raise RuntimeError(
                    f"HPP cannot project waypoint {k} onto {waypoint_states[k]!r} "
                    f"(error {error:.3g})"
                )
        out.append((start, goal))
        start = goal
    return out


def plan(problem, legs, seed: int, max_iterations: int, timeout: float, optimize: bool, arm):
    pinocchio.seed(seed)
    np.random.seed(seed)
    t0 = time.perf_counter()
    nodes, paths, ok, error = 0, [], True, ""
    for a, b in legs:
        problem.initConfig(np.array(a))
        problem.resetGoalConfigs()
        problem.addGoalConfig(np.array(b))
        planner = ManipulationPlanner(problem)
        planner.maxIterations(max_iterations)
        planner.timeOut(max(timeout - (time.perf_counter() - t0), 0.1))
        try:
            paths.append(planner.solve())
        except Exception as e:  # HPP raises when the iteration or time limit is reached
            ok, error = False, str(e).splitlines()[0] if str(e) else type(e).__name__
        roadmap = planner.roadmap()
        nodes += len(roadmap.nodes()) if hasattr(roadmap, "nodes") else 0
        if not ok:
            break
    dt = time.perf_counter() - t0
    out = {"seed": seed, "success": ok, "time_s": dt, "nodes": nodes}
    if error:
        out["error"] = error
    if ok and optimize:
        raw = sum(arm_length(p, arm) for p in paths)
        t1 = time.perf_counter()
        opt = [RandomShortcut(problem).optimize(p) for p in paths]
        out.update(
            raw_arm_length=raw,
            arm_length=sum(arm_length(p, arm) for p in opt),
            optimize_s=time.perf_counter() - t1,
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("problem", type=Path)
    ap.add_argument("--seeds", type=int, nargs=2, default=[1, 20], metavar=("FIRST", "LAST"))
    ap.add_argument("--max-iterations", type=int, default=5000)
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--optimize", action="store_true")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    spec = json.loads(args.problem.read_text())
    try:
        _robot, problem, graph = build(spec)
        legs = hpp_legs(graph, spec["legs"], spec.get("waypoint_states", []))
    except RuntimeError as e:  # a problem HPP's graph factory cannot pose
        runs = [
            {
                "seed": s,
                "success": False,
                "time_s": float("nan"),
                "nodes": 0,
                "error": str(e),
                "not_posed": True,
            }
            for s in range(args.seeds[0], args.seeds[1] + 1)
        ]
        args.out.write_text(json.dumps({"system": "HPP 9.0.2", "runs": runs}, indent=1))
        return
    runs = [
        plan(
            problem,
            legs,
            s,
            args.max_iterations,
            args.timeout,
            args.optimize,
            spec["arm_q_indices"],
        )
        for s in range(args.seeds[0], args.seeds[1] + 1)
    ]
    args.out.write_text(json.dumps({"system": "HPP 9.0.2", "runs": runs}, indent=1))


if __name__ == "__main__":
    main()
