"""Several objects: graphs (states, transitions, level-set twins, stacking surfaces) against an
enumeration written here, and a planned swap checked by an independent collision and
constraint check of its sampled path (Pinocchio + coal on the original meshes, geometry of the
scene computed here, not the planner's checker or projectors)."""

from __future__ import annotations

import itertools

import coal
import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette.planning.graph import LevelSetEdge, WaypointEdge
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.problem import load_problem
from marionette.planning.solve import plan_problem

PROBLEMS = marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems"


@pytest.fixture(scope="module")
def swap():
    return load_problem(PROBLEMS / "ur10_swap.yaml")


@pytest.fixture(scope="module")
def tower():
    return load_problem(PROBLEMS / "ur10_tower.yaml")


def expected_states(grippers, handles):
    """Every assignment of distinct handles (or nothing) to the grippers (no rules)."""
    out = set()
    for k in range(len(grippers) + 1):
        for gs in itertools.combinations(grippers, k):
            for hs in itertools.permutations(handles, k):
                parts = [f"{g} grasps {h}" for g, h in zip(gs, hs)]  # gripper order
                out.add(" : ".join(parts) or "free")
    return out


@pytest.mark.parametrize("which", ["swap", "tower"])
def test_states_and_transitions_of_several_objects(which, swap, tower):
    problem = {"swap": swap, "tower": tower}[which]
    graph = graph_from_settings(problem)
    objects = sorted(problem.objects)
    handles = [f"{o}/top" for o in objects]
    grippers = ["ur10/gripper"]
    assert {s.name for s in graph.main_states()} == expected_states(grippers, handles)
    tops = {e.name: e for e in graph.top_edges()}
    for h in handles:
        grasp, release = f"ur10/gripper > {h} | f", f"ur10/gripper < {h} | 0-{handles.index(h)}"
        assert isinstance(tops[grasp], WaypointEdge) and isinstance(tops[release], WaypointEdge)
        assert tops[grasp].to_state is tops[release].from_state
        # A release of one object while the others stay placed: its level-set twin copies
        # the object's placement from another component; a grasp of a 6-D handle has none.
        twin = tops[release + "_ls"]
        assert isinstance(twin, LevelSetEdge) and twin.leaf_objects == [h.split("/")[0]]
        assert grasp + "_ls" not in tops
        # pre-grasp, intersection, pre-placement waypoints on both
        assert len(tops[grasp].sub_edges) == 4 and len(twin.sub_edges) == 4
    loops = [n for n in tops if n.startswith("Loop |")]
    assert len(loops) == len(graph.main_states())
    assert len(tops) == len(loops) + 3 * len(handles)


def test_stacking_surfaces_exclude_the_object_itself(tower):
    graph = graph_from_settings(tower)
    for o in tower.objects:
        place = next(c for c in graph.states["free"].constraints if c.name == f"place_{o}")
        surfaces = {e.name for _, e in place.pairs}
        assert surfaces == {"table/top"} | {f"{x}/top_face" for x in tower.objects if x != o}


# ---------------------------------------------------------------------------------- swap
TABLE_TOP_Z = 0.73  # models/objects/table.yaml, table at z = 0
BOX_HALF = 0.06  # models/objects/box: a 12 cm cube
TABLE_X, TABLE_Y = (0.95 - 0.35, 0.95 + 0.35), (-0.7, 0.7)


def independent_geometry(problem):
    """Collision model of the scene from the problem's URDF meshes (not the planner's convex
    hulls), every pair of bodies on different joints except adjacent links (SRDF + file)."""
    geom = problem.geom_model.copy()
    data = pin.GeometryData(geom)
    return geom, data


def gripper_to_handle(data, problem, obj, gripper="ur10/gripper"):
    """(distance, angle) between the gripper frame and ``obj``'s handle frame."""
    g = data.oMf[problem.grippers[gripper].frame_id]
    h = data.oMf[problem.handles[f"{obj}/top"].frame_id]
    M = g.actInv(h)
    return np.linalg.norm(M.translation), np.linalg.norm(pin.log3(M.rotation))


def held(data, problem, obj):
    """Is ``obj`` held: its handle frame on the gripper frame (1e-3)?"""
    d, a = gripper_to_handle(data, problem, obj)
    return d < 1e-3 and a < 1e-3


def approached(data, problem, obj):
    """Is the gripper on ``obj``'s handle axis within the pre-grasp distance (the approach,
    where the open fingers come around the box)?"""
    d, a = gripper_to_handle(data, problem, obj)
    clearance = problem.grippers["ur10/gripper"].clearance + problem.handles[f"{obj}/top"].clearance
    return d < clearance + 1e-3 and a < 1e-2


def resting(q, problem, obj):
    """Is ``obj`` upright on the table (bottom face at the table top, centre over the top)?"""
    i = problem.objects[obj].idx_q
    X = pin.XYZQUATToSE3(q[i : i + 7])
    return (
        abs(X.translation[2] - BOX_HALF - TABLE_TOP_Z) < 2e-3
        and X.rotation[2, 2] > 1 - 1e-4
        and TABLE_X[0] < X.translation[0] < TABLE_X[1]
        and TABLE_Y[0] < X.translation[1] < TABLE_Y[1]
    )


@pytest.mark.slow
def test_planned_swap_passes_an_independent_check(swap):
    """Plan the swap (optimised, as `marionette plan` does), sample the plan every 5 mm of arc
    and check every sample with Pinocchio + coal on the meshes, and the manipulation rules
    computed here: start and goal exact; each box either held by the gripper or resting on the
    table, never both moving and unheld; hand-box contact allowed only for the box held or
    approached (gripper on its handle axis within the pre-grasp distance)."""
    p = swap
    sol = plan_problem(p, seed=3)
    assert sol.success, sol.result.reason
    paths = sol.paths
    assert np.allclose(paths[0].start, p.q_init) and np.allclose(paths[-1].end, p.q_goal)
    for a, b in zip(paths, paths[1:]):
        assert np.array_equal(a.end, b.start)
    model, data = p.model, p.model.createData()
    geom, gdata = independent_geometry(p)
    names = [o.name for o in geom.geometryObjects]
    hand = {
        k
        for k, o in enumerate(geom.geometryObjects)
        if any(x in o.name for x in ("gripper_link", "finger_left", "finger_right"))
    }
    box_geoms = {o: {k for k, n in enumerate(names) if n.startswith(f"{o}/")} for o in p.objects}
    samples = np.vstack([pth.sample(0.005)[1] for pth in paths])
    prev = samples[0]
    for q in samples:
        assert np.all(q[:6] >= p.lower[:6] - 1e-9) and np.all(q[:6] <= p.upper[:6] + 1e-9)
        pin.framesForwardKinematics(model, data, q)
        pin.updateGeometryPlacements(model, data, geom, gdata, q)
        holding = {o for o in p.objects if held(data, p, o)}
        near = {o for o in p.objects if approached(data, p, o)}
        assert len(holding) <= 1
        for o in p.objects:
            i = p.objects[o].idx_q
            if o not in holding:
                assert resting(q, p, o), f"{o} floats at {q[i : i + 3]}"
                assert np.allclose(q[i : i + 7], prev[i : i + 7], atol=1e-6), f"{o} slides"
        for cp in geom.collisionPairs:
            a, b = cp.first, cp.second
            grasp = any(
                (a in hand and b in box_geoms[o]) or (b in hand and a in box_geoms[o]) for o in near
            )
            if grasp:
                continue
            req, res = coal.CollisionRequest(), coal.CollisionResult()
            coal.collide(
                geom.geometryObjects[a].geometry,
                gdata.oMg[a],
                geom.geometryObjects[b].geometry,
                gdata.oMg[b],
                req,
                res,
            )
            assert not res.isCollision(), f"{names[a]} / {names[b]}"
        prev = q
    # Each box was carried at some point, and ends where the other began.
    for a, b in (("box1", "box2"), ("box2", "box1")):
        ia, ib = p.objects[a].idx_q, p.objects[b].idx_q
        assert np.allclose(samples[-1][ia : ia + 3], p.q_init[ib : ib + 3], atol=1e-6)
