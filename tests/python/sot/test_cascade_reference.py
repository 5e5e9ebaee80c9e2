"""The strict hierarchy is exact on every stack shape: ``marionette._core.Hierarchy`` in exact
mode (no damping, no QP regularisation), with the active-set shortcut on and off, against the
independent textbook cascade of tests/python/sot_cascade.py (SVD null spaces, one DAQP QP per
level with slacks) on generated stacks on every bundled robot: equality, inequality-only (at any
position, the last included) and mixed levels, conflicting, repeated and rank-deficient tasks,
singular configurations, joint-velocity bounds binding or not; and the same with a posture
level (unit rows on every joint) inserted at any position, the shape the solver takes from the
rows it leaves out.

Each stack is solved twice by the same Hierarchy (the second time with every target moved, as
the next tick), so that the QP levels start from the last solve's working set: the shortcut's
first guess. Per stack and mode, marionette's v must
* hold the joint-velocity bounds (always feasible: they contain 0) to BOUND_TOLERANCE;
* be optimal at every level given what it achieves at the levels above (the reference's
  ``optimality_gaps``, <= GAP_TOLERANCE): by induction that is the lexicographic optimum, and it
  is what a level solved at a non-optimal point (a +14 % level error) or a level altering the
  ones above (a 6-D task error from 0 to 0.15) fails;
* and, on most stacks, achieve what the reference achieves level by level (<= AGREE_TOLERANCE).
  Where they differ, a level's objective is nearly flat along a direction a level below uses:
  the two cascades' rounding of order 1e-10 on the upper level moves the lower one by O(1); the
  gap check then says which point is the optimum (marionette's, on every stack seen).
Stacks whose projected rows have singular values between RANK_TOLERANCE and 1e-3 of their scale
(``well_posed``) are left out: there the undamped cascade amplifies rounding by up to 1e9.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from marionette import _core
from sot_cascade import (
    ReferenceFailure,
    achieved,
    bundled_robots,
    level_differences,
    optimality_gaps,
    perturbed,
    random_stack,
    robot_kinematics,
    stack_rng,
    textbook_cascade,
    well_posed,
)

BOUND_TOLERANCE = 1e-9  # rad/s (the solver's constraint tolerance)
# A level's objective above its optimum, relative to 1 + that optimum. The reference resolves
# it to ~1e-8 on its worst stacks (a 16-D QP level of TALOS: 1e-8 by DAQP, 4e-8 by proxsuite
# for the same point); the defects this test is for are gaps of 0.06 to 0.15.
GAP_TOLERANCE = 1e-7
AGREE_TOLERANCE = 1e-6  # a level's achieved values vs the reference's, relative
# Known, open, each listed as (robot, seed, shortcut) — a stack is drawn from its robot's name and
# its seed alone (``stack_rng``), so bundling another robot adds stacks and redraws none — so that
# the thousands-of-stacks run guards every other (stack, mode); a listed case that is drawn and
# passes fails the test, so the list stays true. History: with one robot per seed, 4000 stacks
# left 5 defects of 15 after two fixes (a carried row PrepareRows left out as fixed, moved O(1) by
# a 1e10 step along a flat direction: a level above went from 0.71 to 1269; a blocking row
# dependent on the working set's within 1e-10 ended the primal method), then 8 of 4000 with 8
# robots. Drawn per robot (stacks 0-499 of each), one stack never returned: eiquadprog-fast looped
# on a violated row dependent on its active set (fixed in cpp/third_party/eiquadprog). SO-100 stack
# 132, listed as a 1.4 % gap in both modes, was the reference's: its presolve merged two joint
# bounds' rows 4e-7 rad from parallel (a Jacobian entry of 9e-8 tells them apart) and its optimum
# left one bound by 8e-8 rad/s, where marionette held both; such stacks now count as reference
# failures (sot_cascade._level_step). Left:
KNOWN_DEFECTS = {
    # QP failures reported on optimal points (gaps <= 3e-13): eiquadprog's and the primal
    # method's points both left uncertified. (TIAGo 68 and SO-100 4, listed alike, became
    # certified when the reflections moved from Eigen's kernels to column operations: these
    # cases sit on the certificate's rounding edge.)
    ("so100", 476, True): "qp_failures",
    ("so100", 476, False): "qp_failures",
    # The same on a degenerate vertex (level 1: 14 rows at a bound on 13 DoF plus 8 slacks, gaps
    # <= 3e-14): the multiplier of one row is 2.5e-10 on the wrong side, 1.0-1.5 x the dual
    # tolerance, whichever working set is tried. Appeared when the reflections became raw loops
    # (another rounding), as TIAGo 324 did with four running sums in their dot product.
    ("tiago", 238, True): "qp_failures",
    ("tiago", 238, False): "qp_failures",
}


def bounds_overshoot(levels: list[list[dict]], shapes: list[str], v: np.ndarray) -> float:
    if shapes[0] != "bounds":
        return 0.0
    (task,) = levels[0]
    Jv = task["jacobian"] @ v
    return float(np.max(np.abs(Jv - np.clip(Jv, task["lower"], task["upper"]))))


def with_posture(name: str, rng: np.random.Generator) -> tuple[list[list[dict]], list[str]]:
    """A random stack with a posture level inserted at a random position below the bounds: unit
    rows on every joint (what real stacks end with), so that it is solved on its Gram matrix,
    from the rows it leaves out (the free flyer's) when they are fewer than it covers."""
    levels, shapes = random_stack(name, rng)
    nv = levels[0][0]["jacobian"].shape[1]
    columns = list(range(robot_kinematics(name).base_dofs, nv))
    posture = {
        "jacobian": np.eye(nv)[columns],
        "lower": rng.normal(0.0, 0.3, len(columns)),
        "unit_columns": columns,
    }
    first = 1 if shapes[0] == "bounds" else 0
    at = int(rng.integers(first, len(levels) + 1))
    levels.insert(at, [posture])
    shapes.insert(at, "posture")
    return levels, shapes


def check_stacks(seeds: range, make_stack=random_stack) -> dict:
    """Stacks number ``seeds`` of every bundled robot (drawn by ``make_stack``)."""
    robots = bundled_robots()
    counts = {"stacks": 0, "left_out": 0, "reference_failures": 0, "agree": 0, "known_defects": 0}
    worst = {"gap": 0.0, "overshoot": 0.0, "difference": 0.0, "shortcut_levels": 0}
    failures = []
    for name, seed in ((name, seed) for name in robots for seed in seeds):
        rng = stack_rng(name, seed)
        levels, shapes = make_stack(name, rng)
        moved = perturbed(levels, rng)
        if not (well_posed(levels) and well_posed(moved)):
            counts["left_out"] += 1
            continue
        try:
            reference = textbook_cascade(moved)
        except ReferenceFailure:
            counts["reference_failures"] += 1
            continue
        for shortcut in (True, False):
            hierarchy = _core.Hierarchy(levels, active_set_shortcut=shortcut)
            hierarchy.solve(levels)
            v, report = hierarchy.solve(moved)
            try:
                gaps = optimality_gaps(moved, v)
            except ReferenceFailure:
                counts["reference_failures"] += 1
                continue
            counts["stacks"] += 1
            gap, overshoot = max(gaps), bounds_overshoot(moved, shapes, v)
            scales = [1.0 + np.max(np.abs(achieved(lv, reference.v))) for lv in moved]
            difference = max(
                d / s for d, s in zip(level_differences(moved, v, reference.v), scales, strict=True)
            )
            counts["agree"] += difference <= AGREE_TOLERANCE
            worst["gap"] = max(worst["gap"], gap)
            worst["overshoot"] = max(worst["overshoot"], overshoot)
            worst["difference"] = max(worst["difference"], difference)
            worst["shortcut_levels"] += report["num_active_set"] if shortcut else 0
            failed = gap > GAP_TOLERANCE or overshoot > BOUND_TOLERANCE or report["qp_failures"]
            known = (
                KNOWN_DEFECTS.get((name, seed, shortcut)) if make_stack is random_stack else None
            )
            if known and not failed:
                failures.append(
                    f"seed {seed} {name} shortcut={shortcut}: listed as {known}, now passes"
                )
            elif known:
                counts["known_defects"] += 1
            elif failed:
                failures.append(
                    f"seed {seed} {name} {shapes} shortcut={shortcut}: gaps "
                    f"{[f'{g:.2g}' for g in gaps]}, bound overshoot {overshoot:.2g}, "
                    f"qp_failures {report['qp_failures']}"
                )
    print(counts, worst)
    assert not failures, "\n".join(failures)
    # The filters must not hollow the test out.
    total = len(seeds) * len(robots)
    assert counts["left_out"] <= 0.25 * total, counts
    assert counts["reference_failures"] <= 0.05 * 2 * total, counts
    assert counts["agree"] >= 0.97 * counts["stacks"], counts
    assert worst["shortcut_levels"] > 0.5 * total, worst  # the shortcut was exercised
    return counts


@pytest.mark.slow
def test_every_level_optimal_on_random_stacks():
    check_stacks(range(50))


@pytest.mark.slow
def test_every_level_optimal_on_thousands_of_stacks():
    check_stacks(range(50, 500))


@pytest.mark.slow
def test_every_level_optimal_with_a_posture_level():
    check_stacks(range(60), make_stack=with_posture)


# A TALOS stack (bounds, inequality, equality, equality) on whose first solve, shortcut off, a
# level's QP meets a violated velocity bound dependent on its active rows: eiquadprog-fast as
# released selects it again forever (cpp/third_party/eiquadprog/README.md). Solved in a child
# process, so that a regression fails here instead of hanging the suite.
NEVER_RETURNED = ("talos", 399)

_SOLVE_IN_CHILD = """
import json, sys
import numpy as np
from marionette import _core
from sot_cascade import perturbed, random_stack, stack_rng
rng = stack_rng(sys.argv[1], int(sys.argv[2]))
levels, _ = random_stack(sys.argv[1], rng)
moved = perturbed(levels, rng)
out = {}
for shortcut in (False, True):
    hierarchy = _core.Hierarchy(levels, active_set_shortcut=shortcut)
    hierarchy.solve(levels)
    v, report = hierarchy.solve(moved)
    out[str(shortcut)] = {"v": v.tolist(), "qp_failures": report["qp_failures"]}
print(json.dumps(out))
"""


def test_a_level_qp_with_a_dependent_violated_row_ends_and_is_optimal():
    name, seed = NEVER_RETURNED
    done = subprocess.run(
        [sys.executable, "-c", _SOLVE_IN_CHILD, name, str(seed)],
        capture_output=True,
        text=True,
        timeout=120,
        env={
            **os.environ,
            "PYTHONPATH": os.pathsep.join([*sys.path, os.environ.get("PYTHONPATH", "")]),
        },
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rng = stack_rng(name, seed)
    levels, _ = random_stack(name, rng)
    moved = perturbed(levels, rng)
    for shortcut, solved in json.loads(done.stdout).items():
        gaps = optimality_gaps(moved, np.array(solved["v"]))
        assert max(gaps) <= GAP_TOLERANCE and solved["qp_failures"] == 0, (shortcut, gaps, solved)
