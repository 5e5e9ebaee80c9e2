"""On a free motion, the robot and what it carries keep the problem's clearance from what stays
in place, and what it carries keeps it from the robot's other moving bodies (collision.py's
docstring), checked on planned and optimised plans by brute force: every
path sampled finely, every pair's distance computed by Pinocchio on the planner's geometry, the
still bodies found from their placements along the path (not from the planner's own motion
model). Without the clearance the TALOS plank flip's plans passed fingertips 0.06-0.6 mm above
the table, and the robot, tracking them within millimetres, pressed on it and fell; and the right
hand, leaving the plank to the left one, grazed it (the left hand's servo had moved it by a
centimetre) and pushed it 19 mm / 10 deg in the left hand's fingers.

A pair may come closer than the clearance only on a path one of whose ends is already closer
for that pair, and such an end must be a configuration the planner was given (the start, the
goal, a transition's waypoint), never one it created (a roadmap node, a shortcut's cut)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette.planning.collision import CLEARANCE, CONTACT
from marionette.planning.problem import load_problem
from marionette.planning.solve import plan_problem

PROBLEMS = marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems"
STEP = 0.005  # arc length between samples (rad-like): a few millimetres of a hand's motion
TOLERANCE = 1e-6  # m


def _placements(checker, q: np.ndarray) -> list[pin.SE3]:
    pin.updateGeometryPlacements(
        checker.model, checker.data, checker.geom_model, checker.geom_data, q
    )
    return [pin.SE3(X) for X in checker.geom_data.oMg]


def _distances(checker, q: np.ndarray) -> np.ndarray:
    pin.computeDistances(checker.model, checker.data, checker.geom_model, checker.geom_data, q)
    return np.array([r.min_distance for r in checker.geom_data.distanceResults])


def _rigid_pairs(checker, pairs: np.ndarray, samples: list[np.ndarray]) -> np.ndarray:
    """Per pair: the two geometries' relative placement the same at every sample."""
    first = _placements(checker, samples[0])
    rigid = np.ones(len(pairs), dtype=bool)
    for q in samples[1:]:
        X = _placements(checker, q)
        for k, (a, b) in enumerate(pairs):
            if rigid[k]:
                rigid[k] = (X[a].actInv(X[b])).isApprox(first[a].actInv(first[b]), 1e-9)
    return rigid


def _still(checker, samples: list[np.ndarray]) -> np.ndarray:
    """Per geometry: its world placement the same at every sample."""
    first = _placements(checker, samples[0])
    still = np.ones(len(first), dtype=bool)
    for q in samples[1:]:
        for g, X in enumerate(_placements(checker, q)):
            if still[g] and not X.isApprox(first[g], 1e-9):
                still[g] = False
    return still


@pytest.mark.slow
@pytest.mark.parametrize(
    "problem_file, seed, carries",
    # ur10-box carries its box only along the grasp's waypoints (no free motion); the plank flip
    # carries the plank past the other arm.
    [("ur10_box.yaml", 0, False), ("talos_plank.yaml", 4, True), ("talos_plank.yaml", 6, True)],
)
def test_free_motions_keep_the_clearance_except_at_given_ends(problem_file, seed, carries):
    problem = load_problem(PROBLEMS / problem_file)
    solution = plan_problem(problem, seed=seed)
    assert solution.success
    checker, paths = solution.checker, solution.paths
    pairs = np.array(checker.pairs)
    # Configurations the planner was given: the plan's ends and every end of a transition's
    # waypoint chain (where a free motion meets an approach, or a leaf changes).
    given = [paths[0].start, paths[-1].end]
    for a, b in zip(paths, paths[1:]):
        if a.edge.short != b.edge.short or a.edge.name != b.edge.name:
            given.append(a.end)

    def is_given(q: np.ndarray) -> bool:
        return any(np.array_equal(q, g) for g in given)

    objects = {o.joint_id for o in problem.objects.values()}
    on_object = np.array([g.parentJoint in objects for g in checker.geom_model.geometryObjects])
    carried_pairs = 0
    closest = np.inf
    free_motions = 0
    for p in paths:
        if p.edge.short or p.length <= 0:
            continue
        free_motions += 1
        samples = [p.eval(s) for s in np.linspace(0.0, p.length, max(2, int(p.length / STEP) + 1))]
        still = _still(checker, samples)
        allowed = np.zeros(len(pairs), dtype=bool)
        allowed[list(checker.grasp_contact_pairs(p.edge.grasps))] = True
        carried = (on_object[pairs[:, 0]] | on_object[pairs[:, 1]]) & ~_rigid_pairs(
            checker, pairs, samples
        )
        kept = ((still[pairs[:, 0]] != still[pairs[:, 1]]) | carried) & ~allowed
        carried_pairs += int(np.sum(carried & ~allowed & ~still[pairs[:, 0]] & ~still[pairs[:, 1]]))
        d = np.array([_distances(checker, q) for q in samples])[:, kept]
        closer_at_end = (d[0] < CLEARANCE) | (d[-1] < CLEARANCE)
        for end, closer in ((p.start, d[0] < CLEARANCE), (p.end, d[-1] < CLEARANCE)):
            names = [
                " / ".join(checker.geom_model.geometryObjects[int(g)].name for g in pair)
                for pair in pairs[kept][closer]
            ]
            assert not names or is_given(end), (
                f"{p.edge.name}: a created configuration closer than {CLEARANCE} m: {names}"
            )
        assert np.all(d > CONTACT), p.edge.name
        held = d[:, ~closer_at_end]
        if held.size:
            closest = min(closest, float(held.min()))
            assert held.min() >= CLEARANCE - TOLERANCE, (
                f"{p.edge.name}: {held.min() * 1e3:.2f} mm from a still body or the carried object"
            )
    assert free_motions > 0 and np.isfinite(closest)
    if carries:
        assert carried_pairs > 0, "no object carried past the robot's other bodies: nothing tested"
