"""Prioritised equality / inequality systems (Kanoun's cascade, Dang eq. 2.77–2.81).

Levels are solved in priority order; the solution set of level i is the feasible set of the
levels after it (Dang §2.5.1):

    S_0 = {x : lower ≤ x ≤ upper}
    S_i = argmin_{x ∈ S_(i-1)} ||A_i x − b_i||²                    (equality level, eq. 2.79)
    S_i = argmin_{x ∈ S_(i-1), w} ||w||²  s.t. C_i x − d_i ≤ w      (inequality level, eq. 2.80)

Equality levels are kept exactly by a null-space parametrisation x = x0 + Z z (Z orthonormal):
after level i, Z ← Z N(A_i Z), so lower levels cannot change A_i x. Inequality levels become
constraints C_i x ≤ d_i + w_i* of every lower level (w_i* the least violation reached).

Each level is one small least-squares problem. When its minimiser violates a bound or an
inequality, the level's QP in the free space (box and the rows of the inequality levels above)
is solved by DAQP's dual active set, exact and a few tens of microseconds at these sizes. If
DAQP reports no optimum, the violated rows are held as equalities and the KKT system re-solved;
that answer is kept only if it is feasible and its multipliers have the right signs (then it is
the QP's optimum). Otherwise proxsuite solves the level's QP, built by constraint generation:
first with the violated rows only, then adding rows until none is violated, which returns the
optimum of the full QP (the reduced problem is a relaxation whose optimum is feasible). Levels
marked ``best_effort`` (regularisation) then scale their step down to feasibility instead.

A small damping μ||x||² (Levenberg–Marquardt) regularises each level; its effect vanishes at a
fixed point of the outer Gauss–Newton loop (x = 0 there).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import daqp
import numpy as np
from proxsuite import proxqp

from marionette.footsteps.errors import InvalidProblem

_INF = 1e20


@dataclass
class Level:
    """One priority level: ``matrix @ x == vector`` (equality) or ``matrix @ x <= vector``."""

    name: str
    matrix: np.ndarray  # (m, n)
    vector: np.ndarray  # (m,)
    equality: bool
    # Best effort (regularisation levels): when bounds or inequalities bind and the active-set
    # paths fail, the step is scaled down to stay feasible (SNS task scaling) instead of
    # solving a proxsuite QP.
    best_effort: bool = False

    @staticmethod
    def task(
        name: str, jacobian: np.ndarray, error: np.ndarray, best_effort: bool = False
    ) -> Level:
        """Linearised task e(q) → 0: J x = −e (one Gauss–Newton step)."""
        return Level(name, jacobian, -error, True, best_effort)

    @staticmethod
    def constraint(name: str, jacobian: np.ndarray, value: np.ndarray) -> Level:
        """Linearised constraint g(q) ≥ 0: g + J x ≥ 0, i.e. −J x ≤ g."""
        return Level(name, -jacobian, value, False)


@dataclass
class LevelReport:
    name: str
    equality: bool
    residual: float  # equality: ||A x − b||; inequality: ||max(C x − d, 0)||
    used_qp: bool


@dataclass
class HierarchySolution:
    x: np.ndarray
    levels: list[LevelReport] = field(default_factory=list)
    qp_solves: int = 0
    x_after: list[np.ndarray] = field(default_factory=list)  # x once each level was solved


@dataclass
class HierarchySettings:
    damping: float = 1e-4  # μ of μ||x||² in every level
    rank_tolerance: float = 1e-7  # singular values below this (× max(1, σ_max)) span the null space
    feasibility_tolerance: float = 1e-7
    # proxsuite eps_abs: its residual was seen to floor at 1e-8..3e-9 on degenerate vertices
    qp_eps: float = 1e-7
    qp_max_iter: int = 300
    # (Ruiz preconditioner, relaxation [m|rad]) tried in turn, see _Cascade._proxqp.
    qp_attempts: tuple[tuple[bool, float], ...] = (
        (True, 0.0),
        (False, 0.0),
        (False, 1e-6),
        (True, 1e-5),
        (False, 1e-5),
        (False, 1e-4),
    )


def solve_hierarchy(
    levels: list[Level],
    lower: np.ndarray,
    upper: np.ndarray,
    settings: HierarchySettings | None = None,
) -> HierarchySolution:
    """Solve the prioritised system ``levels`` (highest priority first) within box bounds.

    ``lower``/``upper`` (n,) are hard bounds of every level (joint and step limits); they must
    satisfy lower ≤ 0 ≤ upper... or at least lower ≤ upper, in which case x is first brought
    inside. Returns x (n,) and one report per level.
    """
    s = settings or HierarchySettings()
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    n = lower.shape[0]
    if upper.shape != (n,) or np.any(lower > upper):
        raise InvalidProblem("bounds must have the same shape and satisfy lower <= upper")
    for level in levels:
        if (
            level.matrix.ndim != 2
            or level.matrix.shape[1] != n
            or level.vector.shape != (level.matrix.shape[0],)
        ):
            raise InvalidProblem(
                f"level {level.name!r}: matrix {level.matrix.shape} and vector "
                f"{level.vector.shape} do not fit {n} variables"
            )
    state = _Cascade(n, lower, upper, s)
    reports, x_after = [], []
    for i, level in enumerate(levels):
        used = False
        if level.matrix.shape[0]:
            if level.equality:
                used = state.equality(
                    level.matrix,
                    level.vector,
                    last=i == len(levels) - 1,
                    best_effort=level.best_effort,
                )
            else:
                used = state.inequality(level.matrix, level.vector)
        reports.append(LevelReport(level.name, level.equality, 0.0, used))
        x_after.append(state.x0.copy())
    # The QPs meet the box to proxsuite's tolerance (~1e-7); return a point inside it.
    x = np.clip(state.x0, lower, upper)
    for report, level in zip(reports, levels):
        r = level.matrix @ x - level.vector
        report.residual = float(np.linalg.norm(r if level.equality else np.maximum(r, 0.0)))
    return HierarchySolution(x, reports, state.qp_solves, x_after)


class _Cascade:
    """Running state of the cascade: x = x0 + Z z, inequalities G x ≤ h, bounds.

    ``Z`` (n × r) spans the directions left free by the equality levels; its orthogonal
    complement P (:meth:`_complement`) writes them as Pᵀ x = Pᵀ x0 in the QPs.
    """

    def __init__(self, n: int, lower: np.ndarray, upper: np.ndarray, s: HierarchySettings):
        self.n, self.s = n, s
        self.lower, self.upper = lower, upper
        # Start inside the box: the point of the box nearest to 0.
        self.x0 = np.clip(np.zeros(n), lower, upper)
        self.Z: np.ndarray | None = None  # None means identity (no equality level yet)
        self.G = np.zeros((0, n))
        self.h = np.zeros(0)
        self.qp_solves = 0

    @property
    def free_dim(self) -> int:
        return self.n if self.Z is None else self.Z.shape[1]

    def _Zmul(self, M: np.ndarray) -> np.ndarray:
        return M if self.Z is None else M @ self.Z

    def _lift(self, z: np.ndarray) -> np.ndarray:
        return z if self.Z is None else self.Z @ z

    # -- equality level -----------------------------------------------------------------------
    def equality(
        self, A: np.ndarray, b: np.ndarray, last: bool = False, best_effort: bool = False
    ) -> bool:
        r = self.free_dim
        if r == 0:
            return False
        M = self._Zmul(A)  # (m, r)
        rhs = b - A @ self.x0
        mu = self.s.damping
        Zt_x0 = self.x0 if self.Z is None else self.Z.T @ self.x0
        # Damped least squares in the free space: (MᵀM + μI) z = Mᵀ rhs − μ Zᵀ x0.
        H = M.T @ M
        H.flat[:: r + 1] += mu
        g = M.T @ rhs - mu * Zt_x0
        if last:
            z = np.linalg.solve(H, g)
        else:
            # The SVD M = U S Vᵀ the null space needs below also solves the system:
            # MᵀM + μI = V diag(σ² + μ) Vᵀ (σ = 0 past the rank).
            _, sv, vt = np.linalg.svd(M, full_matrices=True)
            s2 = np.zeros(r)
            s2[: sv.shape[0]] = sv * sv
            z = vt.T @ ((vt @ g) / (s2 + mu))
        dx_ls = self._lift(z)
        dx: np.ndarray | None = dx_ls
        used_qp = False
        if not self._feasible(self.x0 + dx_ls):
            dx = self._active_set_qp(H, g)
            if dx is None:
                dx = self._clamped_least_squares(H, g, dx_ls)
            if dx is None and best_effort:
                dx = self._scaled(dx_ls)
        if dx is None:
            # Same problem over the full x with Pᵀ dx = 0: min ||A x − b||² + μ||x||².
            Hx = 2.0 * (A.T @ A)
            Hx.flat[:: self.n + 1] += 2.0 * mu
            gx = 2.0 * (A.T @ (A @ self.x0 - b) + mu * self.x0)
            dx = self._qp(Hx, gx, dx_ls)
            used_qp = True
        self.x0 = self.x0 + dx
        if last:
            return used_qp
        # Lower levels move only in the null space of M (keep A x exactly).
        tol = self.s.rank_tolerance * max(1.0, sv[0] if sv.size else 0.0)
        rank = int(np.sum(sv > tol))
        N = vt[rank:].T  # (r, r - rank)
        self.Z = N if self.Z is None else self.Z @ N
        return used_qp

    # -- inequality level ---------------------------------------------------------------------
    def inequality(self, C: np.ndarray, d: np.ndarray) -> bool:
        violation = C @ self.x0 - d
        if np.all(violation <= self.s.feasibility_tolerance) or self.free_dim == 0:
            # x0 satisfies the level: w* = max(violation, 0) (0 unless no freedom is left).
            self._append(C, d + np.maximum(violation, 0.0))
            return False
        n, m = self.n, C.shape[0]
        mu = self.s.damping
        # Variables (dx, w): min ||w||² + μ||x0 + dx||²  s.t.  C dx − w ≤ d − C x0.
        H = np.zeros((n + m, n + m))
        H[np.diag_indices(n)] = 2.0 * mu
        H[n + np.arange(m), n + np.arange(m)] = 2.0
        g = np.concatenate([2.0 * mu * self.x0, np.zeros(m)])
        extra_C = np.hstack([C, -np.eye(m)])
        extra_u = d - C @ self.x0
        guess = np.concatenate([np.zeros(n), np.maximum(violation, 0.0)])
        y = self._qp(H, g, guess, extra=(extra_C, extra_u), n_extra_vars=m)
        self.x0 = self.x0 + y[:n]
        self._append(C, d + np.maximum(C @ self.x0 - d, 0.0))
        return True

    def _active_set_qp(self, H: np.ndarray, g: np.ndarray) -> np.ndarray | None:
        """The level's QP in the free space, min ½zᵀHz − gᵀz s.t. the box on x0 + Z z and the
        cascade's rows G (x0 + Z z) ≤ h, by DAQP's dual active set (Arnström et al. 2022):
        exact, and tens of microseconds for these sizes where proxsuite's ADMM took a
        millisecond. Returns dx = Z z, or None when DAQP reports no optimum (the caller falls
        back to proxsuite). As in :meth:`_qp`, rows x0 already violates by a rounding error are
        relaxed to keep z = 0 feasible."""
        tol = self.s.feasibility_tolerance
        upper = (
            np.concatenate(
                [np.maximum(self.upper - self.x0, 0.0), np.maximum(self.h - self.G @ self.x0, 0.0)]
            )
            + tol
        )
        lower = np.concatenate(
            [np.minimum(self.lower - self.x0, 0.0) - tol, np.full(self.G.shape[0], -_INF)]
        )
        if self.Z is None:
            # z = dx: the box is DAQP's simple bounds (the first n entries of upper/lower
            # when they outnumber A's rows), far cheaper than n identity rows.
            A = self.G
        else:
            A = np.vstack([self.Z, self.G @ self.Z]) if self.G.shape[0] else self.Z
        z, _, exitflag, _ = daqp.solve(H, -g, np.ascontiguousarray(A), upper, lower, primal_tol=tol)
        self.qp_solves += 1
        if exitflag != 1:
            return None
        return self._lift(z)

    def _clamped_least_squares(
        self, H: np.ndarray, g: np.ndarray, dx: np.ndarray
    ) -> np.ndarray | None:
        """Fast exact path when few rows bind: min ½zᵀHz − gᵀz with the violated rows (bounds
        and the cascade's inequalities) held as equalities, as in saturation in the null space
        (Flacco et al. 2012), adding rows while new ones are violated. The result is returned
        only if it is feasible and satisfies the KKT sign conditions (every held row pushes
        outwards), which makes it the QP's optimum; otherwise None and proxsuite solves the QP.
        """
        tol = self.s.feasibility_tolerance
        Zr = np.eye(self.n) if self.Z is None else self.Z
        GZ = self.G @ Zr
        x = self.x0 + dx
        upper = np.zeros(self.n, dtype=bool)
        lower = np.zeros(self.n, dtype=bool)
        rows = np.zeros(self.G.shape[0], dtype=bool)
        r = H.shape[0]
        held = held_rows = nu = None
        for _ in range(self.n + self.G.shape[0]):
            new_upper, new_lower = x > self.upper + tol, x < self.lower - tol
            new_rows = self.G @ x > self.h + tol
            if not (new_upper.any() or new_lower.any() or new_rows.any()):
                break
            upper |= new_upper
            lower |= new_lower
            rows |= new_rows
            held = np.flatnonzero(upper | lower)
            held_rows = np.flatnonzero(rows)
            m = held.shape[0] + held_rows.shape[0]
            kkt = np.zeros((r + m, r + m))
            kkt[:r, :r] = H
            kkt[r : r + held.shape[0], :r] = Zr[held]
            kkt[r + held.shape[0] :, :r] = GZ[held_rows]
            kkt[:r, r:] = kkt[r:, :r].T
            rhs = np.empty(r + m)
            rhs[:r] = g
            rhs[r : r + held.shape[0]] = (
                np.where(upper[held], self.upper[held], self.lower[held]) - self.x0[held]
            )
            rhs[r + held.shape[0] :] = self.h[held_rows] - self.G[held_rows] @ self.x0
            try:
                sol = np.linalg.solve(kkt, rhs)
            except np.linalg.LinAlgError:
                return None
            if np.abs(kkt @ sol - rhs).max() > 1e-9:  # dependent held rows
                return None
            nu = sol[r:]
            x = self.x0 + Zr @ sol[:r]
        else:
            return None
        if nu is None or held is None:
            return x - self.x0
        # Hz + Cᵀν = g: upper bounds and ≤ rows hold with ν ≥ 0, lower bounds with ν ≤ 0.
        sign = np.ones(nu.shape[0])
        sign[: held.shape[0]] = np.where(upper[held], 1.0, -1.0)
        if (sign * nu < -1e-9).any():
            return None
        return x - self.x0

    def _scaled(self, dx: np.ndarray) -> np.ndarray:
        """s·dx with the largest s ∈ [0, 1] keeping x0 + s·dx inside every row (x0 inside)."""
        tol = self.s.feasibility_tolerance
        s = 1.0
        for a, room in (
            (dx, self.upper - self.x0),
            (-dx, self.x0 - self.lower),
            (self.G @ dx, self.h - self.G @ self.x0),
        ):
            moving = a > 1e-15
            if np.any(moving):
                s = min(s, float(np.min(np.maximum(room[moving] + tol, 0.0) / a[moving])))
        return max(s, 0.0) * dx

    def _append(self, C: np.ndarray, h: np.ndarray) -> None:
        """Adds rows C x ≤ h for the levels below, except those the box implies: max over the
        box of C_i x = Σ_j max(C_ij l_j, C_ij u_j) ≤ h_i. Every point the cascade keeps is in
        the box, so such a row never binds; dropping it spares the QPs and the feasibility
        checks (e.g. the non-overlap rows of steps whose width limits already keep them apart).
        """
        with np.errstate(invalid="ignore"):  # 0·inf on unbounded variables
            reach = np.where(C > 0.0, C * self.upper, 0.0) + np.where(C < 0.0, C * self.lower, 0.0)
        binding = ~(reach.sum(axis=1) <= h)
        if not binding.all():
            C, h = C[binding], h[binding]
        self.G = np.vstack([self.G, C])
        self.h = np.concatenate([self.h, h])

    def _complement(self) -> np.ndarray:
        """P (n × (n − r)): orthonormal basis of the directions fixed by the equality levels
        (orthogonal complement of Z), computed only when a QP needs it."""
        if self.Z is None:
            return np.zeros((self.n, 0))
        u, _, _ = np.linalg.svd(self.Z, full_matrices=True)
        return u[:, self.Z.shape[1] :]

    def _feasible(self, x: np.ndarray) -> bool:
        tol = self.s.feasibility_tolerance
        if (x < self.lower - tol).any() or (x > self.upper + tol).any():
            return False
        return not self.G.shape[0] or not (self.G @ x > self.h + tol).any()

    # -- QP with constraint generation ------------------------------------------------------------
    def _qp(
        self,
        H: np.ndarray,
        g: np.ndarray,
        guess: np.ndarray,
        extra: tuple[np.ndarray, np.ndarray] | None = None,
        n_extra_vars: int = 0,
    ) -> np.ndarray:
        """min ½ yᵀHy + gᵀy over y = (dx, extra vars) s.t. Pᵀ dx = 0, the cascade's rows,
        the box on x0 + dx and the ``extra`` rows. Returns y."""
        nvar = self.n + n_extra_vars
        tol = self.s.feasibility_tolerance
        rows = [np.hstack([self.G, np.zeros((self.G.shape[0], n_extra_vars))])]
        # x0 may sit outside a row by a rounding error (accepted by an earlier level within
        # ``tol``): relax the cascade's rows so that dx = 0 stays feasible; the QP is never
        # spuriously infeasible and never ends farther outside than where it started. The
        # ``extra`` rows (a level's own, with slack) are feasible through their slack.
        hi = [np.maximum(self.h - self.G @ self.x0, 0.0) + tol]
        if extra is not None:
            rows.append(extra[0])
            hi.append(extra[1])
        R = np.vstack(rows)
        hi_all = np.concatenate(hi)
        lo_all = np.full(hi_all.shape[0], -_INF)
        l_box = np.concatenate(
            [np.minimum(self.lower - self.x0, 0.0) - tol, np.full(n_extra_vars, -_INF)]
        )
        u_box = np.concatenate(
            [np.maximum(self.upper - self.x0, 0.0) + tol, np.full(n_extra_vars, _INF)]
        )
        P = self._complement()
        E = np.hstack([P.T, np.zeros((P.shape[1], n_extra_vars))])

        def violated(y: np.ndarray) -> np.ndarray:
            return R @ y > hi_all

        active = violated(guess)
        y = guess
        for _ in range(R.shape[0] + 1):
            idx = np.flatnonzero(active)
            y = self._proxqp(H, g, E, R[idx], lo_all[idx], hi_all[idx], (l_box, u_box)).x
            newly = violated(y) & ~active
            if not np.any(newly):
                return y[:nvar]
            active |= newly
        return y[:nvar]

    def _proxqp(self, H, g, E, C, lo, hi, box):
        """proxsuite dense QP (equalities E y = 0, rows lo ≤ C y ≤ hi, box) with y = 0 feasible.

        Lessons from this problem's QPs: proxsuite's default infeasibility threshold
        (eps_primal_inf = 1e-4) reports feasible QPs as infeasible, so it is lowered; rows that
        vanish are dropped (they hold at y = 0). At degenerate vertices (many joint limits and
        closure rows active at once, a nearly flat objective) the feasible set around y = 0 is a
        sliver and proxsuite stalls at a residual near 1e-6; relaxing the inequalities by a few
        micrometres/microradians lets it converge in tens of iterations. Its Ruiz preconditioner
        cured some of these QPs and, with many equality rows (few free dofs), made others
        report infeasibility. So the QP is retried over ``qp_attempts``: preconditioner on/off,
        growing relaxations (the accepted one bounds the violation; the next Gauss–Newton
        iteration starts from the bounds again).
        """
        keep = np.einsum("ij,ij->i", C, C) > 1e-20
        C, lo, hi = C[keep], lo[keep], hi[keep]
        n = H.shape[0]
        b = np.zeros(E.shape[0])
        for precondition, relax in self.s.qp_attempts:
            qp = proxqp.dense.QP(n, E.shape[0], C.shape[0], True)
            qp.settings.eps_abs = self.s.qp_eps
            qp.settings.eps_rel = 0.0
            qp.settings.eps_primal_inf = 1e-12
            qp.settings.eps_dual_inf = 1e-12
            qp.settings.verbose = False
            qp.settings.max_iter = self.s.qp_max_iter
            qp.init(
                H,
                g,
                E,
                b,
                C,
                lo - relax,
                hi + relax,
                box[0] - relax,
                box[1] + relax,
                compute_preconditioner=precondition,
            )
            qp.solve()
            self.qp_solves += 1
            status = qp.results.info.status
            if status == proxqp.QPSolverOutput.PROXQP_SOLVED:
                return qp.results
        raise InvalidProblem(f"QP of the hierarchy not solved: {status}")
