"""The prioritised cascade against closed forms and independent solvers (numpy pseudo-inverse,
scipy's bounded least squares and SLSQP, proxsuite)."""

from __future__ import annotations

import numpy as np
import pytest
from proxsuite import proxqp
from scipy.optimize import lsq_linear, minimize

from marionette.footsteps.errors import InvalidProblem
from marionette.footsteps.hierarchy import HierarchySettings, Level, solve_hierarchy

EXACT = HierarchySettings(damping=1e-9)  # Levenberg–Marquardt damping: O(μ) bias
FREE = 1e6


def test_two_equality_levels_match_the_null_space_projection():
    rng = np.random.default_rng(0)
    n = 8
    A1, b1 = rng.normal(size=(3, n)), rng.normal(size=3)
    A2, b2 = rng.normal(size=(4, n)), rng.normal(size=4)
    # Siciliano–Slotine: x1 = A1⁺ b1, x = x1 + (A2 P1)⁺ (b2 − A2 x1), P1 = I − A1⁺ A1.
    A1p = np.linalg.pinv(A1)
    x1 = A1p @ b1
    P1 = np.eye(n) - A1p @ A1
    x_ref = x1 + np.linalg.pinv(A2 @ P1) @ (b2 - A2 @ x1)
    solution = solve_hierarchy(
        [Level("a", A1, b1, True), Level("b", A2, b2, True)],
        -FREE * np.ones(n),
        FREE * np.ones(n),
        EXACT,
    )
    assert np.allclose(solution.x, x_ref, atol=1e-6)
    assert solution.levels[0].residual < 1e-9


def test_conflicting_lower_level_never_degrades_the_higher_one():
    rng = np.random.default_rng(1)
    n = 5
    A1, b1 = rng.normal(size=(4, n)), rng.normal(size=4)
    A2, b2 = rng.normal(size=(5, n)), rng.normal(size=5)  # full rank: conflicts with A1
    alone = solve_hierarchy(
        [Level("a", A1, b1, True)], -FREE * np.ones(n), FREE * np.ones(n), EXACT
    )
    both = solve_hierarchy(
        [Level("a", A1, b1, True), Level("b", A2, b2, True)],
        -FREE * np.ones(n),
        FREE * np.ones(n),
        EXACT,
    )
    assert both.levels[0].residual == pytest.approx(alone.levels[0].residual, abs=1e-9)
    assert np.allclose(A1 @ both.x, b1, atol=1e-8)


def test_bounds_bind_like_scipy_bounded_least_squares():
    rng = np.random.default_rng(2)
    n = 6
    A, b = rng.normal(size=(3, n)), 3.0 * rng.normal(size=3)
    lower, upper = -0.2 * np.ones(n), 0.3 * np.ones(n)
    # One level, small damping μ: min ||Ax − b||² + μ||x||² within the box.
    mu = 1e-6
    reference = lsq_linear(
        np.vstack([A, np.sqrt(mu) * np.eye(n)]),
        np.concatenate([b, np.zeros(n)]),
        bounds=(lower, upper),
        tol=1e-12,
        lsmr_tol="auto",
    )
    solution = solve_hierarchy(
        [Level("a", A, b, True)], lower, upper, HierarchySettings(damping=mu)
    )
    assert np.all(solution.x >= lower - 1e-7) and np.all(solution.x <= upper + 1e-7)
    assert np.linalg.norm(A @ solution.x - b) == pytest.approx(
        np.linalg.norm(A @ reference.x - b), rel=1e-5
    )


def test_inequality_level_minimises_its_violation_then_holds_it_for_lower_levels():
    # Level 1: x0 + x1 ≤ −1 and x0 − x1 ≤ −1 and −x0 ≤ −0.5 (infeasible together: least
    # squared violation); level 2: x → (3, 3).
    C = np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, 0.0]])
    d = np.array([-1.0, -1.0, -0.5])
    lower, upper = -FREE * np.ones(2), FREE * np.ones(2)
    solution = solve_hierarchy(
        [Level("in", C, d, False), Level("eq", np.eye(2), np.array([3.0, 3.0]), True)],
        lower,
        upper,
        EXACT,
    )
    # Reference for level 1 alone (SLSQP on the slack formulation of eq. 2.80).
    ref = minimize(
        lambda x: np.sum(np.maximum(C @ x - d, 0.0) ** 2),
        np.zeros(2),
        method="Nelder-Mead",
        options={"xatol": 1e-10, "fatol": 1e-14},
    )
    violation = np.maximum(C @ solution.x - d, 0.0)
    assert np.sum(violation**2) == pytest.approx(ref.fun, abs=1e-6)


def test_feasible_inequalities_leave_the_lower_task_exact_where_it_fits():
    C, d = np.array([[1.0, 0.0]]), np.array([1.0])  # x0 ≤ 1
    target = np.array([0.5, 2.0])
    solution = solve_hierarchy(
        [Level("in", C, d, False), Level("eq", np.eye(2), target, True)],
        -FREE * np.ones(2),
        FREE * np.ones(2),
        EXACT,
    )
    assert np.allclose(solution.x, target, atol=1e-8)
    target = np.array([3.0, 2.0])  # now x0 is clipped at 1
    solution = solve_hierarchy(
        [Level("in", C, d, False), Level("eq", np.eye(2), target, True)],
        -FREE * np.ones(2),
        FREE * np.ones(2),
        EXACT,
    )
    assert np.allclose(solution.x, [1.0, 2.0], atol=1e-6)


def test_inconsistent_sizes_are_rejected():
    with pytest.raises(InvalidProblem, match="do not fit 3 variables"):
        solve_hierarchy([Level("a", np.eye(2), np.zeros(2), True)], np.zeros(3), np.ones(3))
    with pytest.raises(InvalidProblem, match="lower <= upper"):
        solve_hierarchy([], np.ones(2), np.zeros(2))


def test_lowest_level_under_bounds_and_rows_is_the_qp_optimum_even_when_best_effort():
    # A goal-like level, then inequality rows, then a best-effort regularisation level whose
    # least-squares step leaves the box in many directions (the footstep chain's preference
    # level): its answer must be the constrained optimum (proxsuite on the same problem), not a
    # feasible but scaled-down step.
    rng = np.random.default_rng(5)
    n = 12
    A1, b1 = rng.normal(size=(2, n)), rng.normal(size=2)
    C, d = rng.normal(size=(3, n)), 0.05 * np.ones(3)
    A2, b2 = np.eye(n), 2.0 * rng.normal(size=n)
    lower, upper = -0.3 * np.ones(n), 0.3 * np.ones(n)
    mu = 1e-6
    solution = solve_hierarchy(
        [
            Level("goal", A1, b1, True),
            Level("rows", C, d, False),
            Level("pref", A2, b2, True, best_effort=True),
        ],
        lower,
        upper,
        HierarchySettings(damping=mu),
    )
    x = solution.x
    assert solution.levels[1].residual < 1e-6 and np.all(np.abs(x) <= 0.3 + 1e-7)  # QP eps
    # Reference: proxsuite's dense QP on the same problem over the full x (A1 x held at what
    # level 1 achieved, the rows and the box as constraints).
    qp = proxqp.dense.QP(n, 2, 3, True)
    qp.settings.eps_abs = 1e-10
    qp.init(
        2.0 * (A2.T @ A2 + mu * np.eye(n)),
        -2.0 * A2.T @ b2,
        A1,
        A1 @ x,
        C,
        np.full(3, -1e20),
        d,
        lower,
        upper,
    )
    qp.solve()
    assert qp.results.info.status == proxqp.QPSolverOutput.PROXQP_SOLVED
    ref = qp.results
    assert np.sum((A2 @ x - b2) ** 2) == pytest.approx(np.sum((A2 @ ref.x - b2) ** 2), rel=1e-6)


def test_rows_the_box_implies_change_nothing_below_them():
    # Inequality rows that the box alone satisfies everywhere (|C_i|·0.3 summed ≤ d_i) are
    # dropped by the cascade; the optimum of the level below must still be the QP's optimum
    # over every row (proxsuite), the binding rows included.
    rng = np.random.default_rng(11)
    n = 10
    implied = rng.normal(size=(6, n))
    implied_d = 0.3 * np.abs(implied).sum(axis=1) + 0.01
    binding = rng.normal(size=(3, n))
    C = np.vstack([implied, binding])
    d = np.concatenate([implied_d, 0.02 * np.ones(3)])
    A2, b2 = np.eye(n), 2.0 * rng.normal(size=n)
    lower, upper = -0.3 * np.ones(n), 0.3 * np.ones(n)
    mu = 1e-6
    solution = solve_hierarchy(
        [Level("rows", C, d, False), Level("pref", A2, b2, True)],
        lower,
        upper,
        HierarchySettings(damping=mu),
    )
    x = solution.x
    # DAQP's primal tolerance plus the cascade's 1e-7 relaxation of its rows.
    assert np.all(C @ x <= d + 1e-6) and np.all(np.abs(x) <= 0.3 + 1e-7)
    assert np.any(binding @ x > 0.02 - 1e-6)  # the problem does bind a kept row
    qp = proxqp.dense.QP(n, 0, C.shape[0], True)
    qp.settings.eps_abs = 1e-10
    qp.init(
        2.0 * (A2.T @ A2 + mu * np.eye(n)),
        -2.0 * A2.T @ b2,
        None,
        None,
        C,
        np.full(C.shape[0], -1e20),
        d,
        lower,
        upper,
    )
    qp.solve()
    assert qp.results.info.status == proxqp.QPSolverOutput.PROXQP_SOLVED
    ref = qp.results.x
    assert np.sum((A2 @ x - b2) ** 2) == pytest.approx(np.sum((A2 @ ref - b2) ** 2), rel=1e-6)
