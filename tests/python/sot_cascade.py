"""An independent strict-priority cascade and random stacks on every bundled robot, to check
``marionette._core.solve_hierarchy`` level by level (tests/python/sot/test_cascade_reference.py;
thousands of stacks in its slow variant).

The cascade is the textbook definition (Kanoun et al. 2011; Dang 2012 eq. 2.77–2.81), written
without anything from cpp/src/sot/hierarchy.cc: with S_0 = R^nv,

    S_l = argmin_{v ∈ S_{l-1}, s}  ½||A_l v - b_l||² + ½||s||²   s.t.  lo_l <= C_l v - s <= hi_l

computed as
* the affine part of S_{l-1} kept as v_{l-1} + range(N) (N from SVD null spaces: the equality
  rows of every level above, held at what they achieved, A_j v = A_j v_j);
* one QP per level in (y, s), v = v_{l-1} + N y, with every inequality row of the levels above
  as a hard constraint (bounds shifted by that level's optimal slack s*_j: the level's optimal
  set is exactly lo_j + s*_j <= C_j v <= hi_j + s*_j), solved by DAQP (dual active set, exact
  up to rounding) on the level's SVD coordinates (y = V z: the objective sees z_1 only, the
  zero-curvature coordinates z_2 get DAQP's proximal iterations);
* a level without any inequality (own or from above) by the pseudo-inverse (SVD).

What a level achieves is unique even when its v is not: A_l v for its equality rows, and the
violation C v - clip(C v, lo, hi) of its inequality rows (``achieved``). Those are compared.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from functools import cache

import daqp
import numpy as np
import pinocchio as pin
import proxsuite
import scipy.optimize

from marionette import robots

RANK_TOLERANCE = 1e-9  # singular values <= this x the level's largest row norm are dependent
CERTIFICATE_TOLERANCE = 1e-10  # KKT residuals of the reference's level QPs (relative)
FEASIBILITY_TOLERANCE = 1e-9  # a carried row left by the reference's optimum (relative)


def _null_space(M: np.ndarray, scale: float) -> tuple[np.ndarray, int]:
    """Orthonormal basis of null(M) (columns) and rank(M) by SVD."""
    if M.shape[0] == 0:
        return np.eye(M.shape[1]), 0
    _, sv, Vt = np.linalg.svd(M, full_matrices=True)
    rank = int(np.sum(sv > RANK_TOLERANCE * scale))
    return Vt[rank:].T, rank


def _split(level: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    nv = level[0]["jacobian"].shape[1]
    eq = [t for t in level if not t.get("inequality")]
    ineq = [t for t in level if t.get("inequality")]
    A = np.vstack([t["jacobian"] for t in eq]) if eq else np.zeros((0, nv))
    b = np.concatenate([t["lower"] for t in eq]) if eq else np.zeros(0)
    C = np.vstack([t["jacobian"] for t in ineq]) if ineq else np.zeros((0, nv))
    lo = np.concatenate([t["lower"] for t in ineq]) if ineq else np.zeros(0)
    hi = np.concatenate([t["upper"] for t in ineq]) if ineq else np.zeros(0)
    return A, b, C, lo, hi


class ReferenceFailure(RuntimeError):
    """The reference QP solver did not return an optimum (reported, never ignored)."""


def _solve_strictly_convex(H, f, A, lo, up, solver: str) -> tuple[np.ndarray, np.ndarray]:
    """min ½x'Hx + f'x  s.t.  lo <= A x <= up (finite bounds), H positive definite: the
    solution and the constraints' multipliers (> 0 at an upper bound, < 0 at a lower one)."""
    n = H.shape[0]
    if solver == "proxsuite":
        qp = proxsuite.proxqp.dense.QP(n, 0, A.shape[0])
        qp.settings.eps_abs, qp.settings.eps_rel, qp.settings.max_iter = 1e-11, 0.0, 20000
        qp.init(H, f, None, None, A, lo, up)
        qp.solve()
        if qp.results.info.status != proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED:
            raise ReferenceFailure(f"proxsuite: {qp.results.info.status} ({n} variables)")
        return np.array(qp.results.x), np.array(qp.results.z)
    x, _, flag, info = daqp.solve(
        np.ascontiguousarray(H),
        f,
        np.ascontiguousarray(A),
        up,
        lo,
        np.zeros(len(up), dtype=np.int32),
        iter_limit=100000,
    )
    if flag != 1:
        raise ReferenceFailure(f"DAQP: exit flag {flag} ({n} variables)")
    return np.asarray(x), np.asarray(info["lam"])


def _certified(H, f, A, lower, upper, x, tol) -> bool:
    """KKT certificate of x for min ½x'Hx + f'x s.t. lower <= A x <= upper: feasible to `tol`
    and stationary, H x + f = A_lo^T μ_lo - A_up^T μ_up with μ >= 0 on the rows at a bound
    (non-negative least squares: degenerate active sets have many multipliers, one suffices)."""
    if not np.all(np.isfinite(x)):
        return False
    value = A @ x
    scale = 1.0 + np.max(np.abs(value), initial=0.0)
    if np.any(value > upper + tol * scale) or np.any(value < lower - tol * scale):
        return False
    gradient = H @ x + f
    at_up = np.isfinite(upper) & (value >= upper - 1e3 * tol * scale)
    at_lo = np.isfinite(lower) & (value <= lower + 1e3 * tol * scale)
    B = np.hstack([A[at_lo].T, -A[at_up].T])
    if B.shape[1] == 0:
        residual = np.linalg.norm(gradient)
    else:
        residual = scipy.optimize.nnls(B, gradient, maxiter=50 * B.shape[1])[1]
    return residual <= 10 * tol * (1.0 + np.linalg.norm(f) + np.linalg.norm(H @ x))


def _polish(H, f, A, lower, upper, x, multipliers):
    """OSQP's polishing: the constraints at a bound with a multiplier imposed as equalities and
    the KKT system on the exact H solved by least squares."""
    n = H.shape[0]
    value = A @ x
    scale = 1.0 + np.max(np.abs(value), initial=0.0)
    big = np.max(np.abs(multipliers), initial=0.0)
    at_upper = (np.abs(value - upper) <= 1e-8 * scale) & (multipliers > 1e-9 * (1.0 + big))
    at_lower = (np.abs(value - lower) <= 1e-8 * scale) & (multipliers < -1e-9 * (1.0 + big))
    active = at_upper | at_lower
    target = np.where(at_upper, upper, lower)[active]
    k = int(active.sum())
    kkt = np.block([[H, A[active].T], [A[active], np.zeros((k, k))]])
    return np.linalg.lstsq(kkt, np.concatenate([-f, target]), rcond=1e-13)[0][:n]


def _solve_qp(H, f, A, lower, upper, solver: str) -> np.ndarray:
    """min ½x'Hx + f'x  s.t.  lower <= A x <= upper (±inf allowed), H >= 0 diagonal (zero on
    the coordinates a level's objective does not see).

    The solver (DAQP, a dual active-set method, or proxsuite, a proximal augmented Lagrangian)
    gets H with its diagonal raised to at least δ (strictly convex, as DAQP needs; the optimum
    then moves by O(δ)); its point is polished (as OSQP does: the constraints it holds at a
    bound imposed as equalities on the exact H, the KKT system solved by least squares) and
    must carry a KKT certificate on the exact problem (_certified). δ = 1e-4 ... 1e-10 (x the
    largest curvature) in turn: a smaller δ when the active set of the perturbed problem was
    not the exact one's; else ReferenceFailure."""
    n = H.shape[0]
    if A.shape[0] == 0:
        return np.linalg.lstsq(H, -f, rcond=1e-13)[0]
    big = 1e20
    lo, up = np.maximum(lower, -big), np.minimum(upper, big)
    top = max(1.0, float(np.abs(H).max()))
    for delta in (1e-4, 1e-6, 1e-8, 1e-10):
        Hd = H.copy()
        np.fill_diagonal(Hd, np.maximum(np.diag(H), delta * top))
        try:
            x, multipliers = _solve_strictly_convex(Hd, f, A, lo, up, solver)
        except ReferenceFailure:
            continue
        for candidate in (_polish(H, f, A, lower, upper, x, multipliers), x):
            if _certified(H, f, A, lower, upper, candidate, CERTIFICATE_TOLERANCE):
                return candidate
    raise ReferenceFailure(f"{solver}: no certified optimum ({n} variables)")


def _level_qp(M, c, G, g_lo, g_hi, C, c_lo, c_hi, solver, scale):
    """min ½||M y - c||² + ½||s||²  s.t.  g_lo <= G y <= g_hi,  c_lo <= C y - s <= c_hi.
    Returns y. Solved in the SVD coordinates of M (y = V z): the Hessian is then diagonal, σ²
    on the coordinates the objective sees, 0 on the others, 1 on the slacks."""
    r, mi = M.shape[1], C.shape[0]
    if r == 0:  # (the carried rows held at one value leave no freedom)
        return np.zeros(0)
    if M.shape[0]:
        _, sv, Vt = np.linalg.svd(M, full_matrices=True)
        V = Vt.T
        # The rank decision: directions with σ <= RANK_TOLERANCE x scale are not seen.
        seen = np.zeros(r, bool)
        seen[: len(sv)] = sv > RANK_TOLERANCE * scale
        curvature = np.zeros(r)
        curvature[: len(sv)] = sv**2
        f_z = -(V.T @ (M.T @ c))
        curvature[~seen], f_z[~seen] = 0.0, 0.0
    else:
        V, curvature, f_z = np.eye(r), np.zeros(r), np.zeros(r)
    H = np.diag(np.concatenate([curvature, np.ones(mi)]))
    f = np.concatenate([f_z, np.zeros(mi)])
    A = np.vstack([np.hstack([G @ V, np.zeros((G.shape[0], mi))]), np.hstack([C @ V, -np.eye(mi)])])
    lower, upper = np.concatenate([g_lo, c_lo]), np.concatenate([g_hi, c_hi])
    # Rows that constrain nothing: both sides infinite, or fixed by the levels above (their
    # direction within the remaining freedom vanishes; widened, they hold at v).
    keep = (np.isfinite(lower) | np.isfinite(upper)) & (np.linalg.norm(A, axis=1) > 1e-12)
    x = _solve_qp(H, f, A[keep], lower[keep], upper[keep], solver)
    return V @ x[:r]


def _presolve(G, lo, hi):
    """The carried rows in the coordinates y of the remaining freedom (lo <= G y <= hi, 0
    inside), made non-degenerate for a dual active-set solver: rows the levels above fixed
    (|G_i| <= RANK_TOLERANCE x the row's norm: a combination of rows held above) dropped;
    rows held at one value (lo = hi: an infeasible level's rows, zero-width boxes) turned into
    y = E w, E a basis of their null space (SVD), and the rows that were combinations of them
    dropped in turn; rows that are parallel (the same row in two tasks, a posture box on
    bounded joints) merged, their intervals intersected. Returns E and the remaining rows in
    w, scaled to unit norm."""
    norms = np.linalg.norm(G, axis=1)
    keep = norms > RANK_TOLERANCE * np.max(norms, initial=1.0)
    G, lo, hi = G[keep] / norms[keep, None], lo[keep] / norms[keep], hi[keep] / norms[keep]
    fixed = hi - lo <= 1e-13
    E, _ = _null_space(G[fixed], 1.0)
    G, lo, hi = G[~fixed] @ E, lo[~fixed], hi[~fixed]
    norms = np.linalg.norm(G, axis=1)  # (the rows were unit: this is what E leaves of them)
    keep = norms > RANK_TOLERANCE
    G, lo, hi = G[keep] / norms[keep, None], lo[keep] / norms[keep], hi[keep] / norms[keep]
    rows, lows, highs = [], [], []
    for g, a, z in zip(G, lo, hi, strict=True):
        for k, h in enumerate(rows):
            cosine = g @ h
            if abs(cosine) > 1.0 - 1e-12:
                a, z = (a, z) if cosine > 0 else (-z, -a)
                lows[k], highs[k] = max(lows[k], a), min(highs[k], z)
                break
        else:
            rows.append(g)
            lows.append(a)
            highs.append(z)
    m = len(rows)
    return E, np.array(rows).reshape(m, E.shape[1]), np.array(lows), np.array(highs)


@dataclass
class CascadeResult:
    v: np.ndarray
    ranks: list[int] = field(default_factory=list)


def _level_step(level, v, N, carried, solver):
    """One level of the cascade from v in v + range(N) with the carried rows (C, lo, hi) as
    hard constraints: returns (y, M, scale), the level's optimum being v + N y."""
    A, b, C, lo, hi = _split(level)
    carried_C, carried_lo, carried_hi = carried
    r = N.shape[1]
    scale = max([1.0] + [np.linalg.norm(row) for row in A])
    M = A @ N
    if r == 0:
        return np.zeros(0), M, scale
    if carried_C.shape[0] == 0 and C.shape[0] == 0:
        U, sv, Vt = np.linalg.svd(M, full_matrices=False)
        rank = int(np.sum(sv > RANK_TOLERANCE * scale))
        return Vt[:rank].T @ ((U[:, :rank].T @ (b - A @ v)) / sv[:rank]), M, scale
    # The carried rows hold at v up to the rounding of the QPs above (~1e-15): their bounds
    # are widened to include v so that the level's QP stays feasible.
    value = carried_C @ v
    E, G, g_lo, g_hi = _presolve(
        carried_C @ N, np.minimum(carried_lo - value, 0.0), np.maximum(carried_hi - value, 0.0)
    )
    w = _level_qp(M @ E, b - A @ v, G, g_lo, g_hi, C @ N @ E, lo - C @ v, hi - C @ v, solver, scale)
    y = E @ w
    # The presolve merged rows within 1.4e-6 rad of parallel: its optimum may leave one of them
    # by (angle x step), e.g. 8e-8 rad/s past a joint bound that a row of 9e-8 made distinct
    # (an SO-100 stack whose hierarchy held every bound and was flagged 1.4 % "worse"). Such a
    # point is not the cascade's: this reference cannot decide the stack.
    moved = carried_C @ (v + N @ y)
    excess = np.max(
        np.maximum(moved - np.maximum(carried_hi, value), np.minimum(carried_lo, value) - moved),
        initial=0.0,
    )
    if excess > FEASIBILITY_TOLERANCE * (1.0 + np.max(np.abs(moved), initial=0.0)):
        raise ReferenceFailure(f"merged near-parallel carried rows: one left by {excess:.1e}")
    return y, M, scale


def _descend(level, v, N, carried):
    """What the level leaves to the levels below, at its optimum v: the basis of the freedom
    left (N times the null space of its equality rows) and the carried rows with its own
    added, their bounds shifted by their slack at v (the level's optimal set is exactly
    lo + s* <= C v <= hi + s*)."""
    A, _, C, lo, hi = _split(level)
    scale = max([1.0] + [np.linalg.norm(row) for row in A])
    rank = 0
    if N.shape[1]:
        null, rank = _null_space(A @ N, scale)
        N = N @ null
    slack = C @ v - np.clip(C @ v, lo, hi)
    carried_C, carried_lo, carried_hi = carried
    carried = (
        np.vstack([carried_C, C]),
        np.concatenate([carried_lo, lo + slack]),
        np.concatenate([carried_hi, hi + slack]),
    )
    return N, carried, rank


def textbook_cascade(levels: list[list[dict]], solver: str = "daqp") -> CascadeResult:
    """The cascade above; levels as for solve_hierarchy (highest priority first)."""
    nv = levels[0][0]["jacobian"].shape[1]
    v, N = np.zeros(nv), np.eye(nv)
    carried = (np.zeros((0, nv)), np.zeros(0), np.zeros(0))
    result = CascadeResult(v)
    for level in levels:
        y, _, _ = _level_step(level, v, N, carried, solver)
        v = v + N @ y
        N, carried, rank = _descend(level, v, N, carried)
        result.ranks.append(rank)
    result.v = v
    return result


def objective(level: list[dict], v: np.ndarray) -> float:
    """The level's objective at v: ||A v - b||² + ||C v - clip(C v, lo, hi)||²."""
    A, b, C, lo, hi = _split(level)
    Cv = C @ v
    return float(np.sum((A @ v - b) ** 2) + np.sum((Cv - np.clip(Cv, lo, hi)) ** 2))


def optimality_gaps(levels: list[list[dict]], v: np.ndarray, solver: str = "daqp") -> list[float]:
    """Per level l: how much worse v does on level l than the best point of the set the
    levels above leave as v achieves them (S_{l-1} of v: their equality rows at A_j v, their
    inequality rows within their bounds shifted by v's slack), f_l(v) - min_{S_{l-1}(v)} f_l,
    relative to 1 + that minimum. A correct hierarchy has every gap 0 (to rounding): every
    level optimal given the levels above, and no level above altered (that would show as a gap
    above). Each level is checked on its own, so a near-degenerate level does not carry its
    rounding into the levels below (as comparing two cascades' solutions does)."""
    nv = len(v)
    N = np.eye(nv)
    carried = (np.zeros((0, nv)), np.zeros(0), np.zeros(0))
    gaps = []
    for level in levels:
        y, _, _ = _level_step(level, v, N, carried, solver)
        best = objective(level, v + N @ y)
        gaps.append((objective(level, v) - best) / (1.0 + best))
        N, carried, _ = _descend(level, v, N, carried)
    return gaps


def achieved(level: list[dict], v: np.ndarray) -> np.ndarray:
    """What a level's optimum fixes: J v of its equality rows and the violation of its
    inequality rows (both unique at the cascade's optimum)."""
    out = []
    for t in level:
        Jv = t["jacobian"] @ v
        out.append(Jv - np.clip(Jv, t["lower"], t["upper"]) if t.get("inequality") else Jv)
    return np.concatenate(out)


def level_differences(levels, v, v_ref) -> list[float]:
    """Per level: max |achieved(v) - achieved(v_ref)|."""
    return [float(np.max(np.abs(achieved(lv, v) - achieved(lv, v_ref)))) for lv in levels]


def bound_violation(levels, v, v_ref) -> float:
    """The largest excess of an inequality row over what the reference achieves for it (0 when
    its level is feasible): bounds that must hold, measured."""
    worst = 0.0
    for level in levels:
        for t in level:
            if t.get("inequality"):
                Jv = t["jacobian"] @ v
                ref = t["jacobian"] @ v_ref
                allowed = np.abs(ref - np.clip(ref, t["lower"], t["upper"]))
                excess = np.abs(Jv - np.clip(Jv, t["lower"], t["upper"])) - allowed
                worst = max(worst, float(np.max(excess)))
    return worst


# --- Random stacks on the bundled robots ---------------------------------------------------------


@dataclass
class RobotKinematics:
    name: str
    model: pin.Model
    base_dofs: int  # velocity coordinates of the base (6 free flyer, 3 planar, 0 fixed)
    frames: list[int]  # body frames (on a moving joint) a task may use


@cache
def robot_kinematics(name: str) -> RobotKinematics:
    model, _ = robots.load_pinocchio(name, with_collision=False)
    base = {"free_flyer": 6, "planar": 3, "fixed": 0}[robots.robot(name).base]
    frames = [
        i for i, f in enumerate(model.frames) if f.type == pin.FrameType.BODY and f.parentJoint > 0
    ]
    return RobotKinematics(name, model, base, frames)


def stack_rng(name: str, seed: int) -> np.random.Generator:
    """The random stream of a robot's stack number ``seed``: the same whatever else is bundled."""
    return np.random.default_rng([seed, zlib.crc32(name.encode())])


def bundled_robots() -> list[str]:
    """Every robot on the search path (models/ and any added later, generically)."""
    return robots.robot_names()


def random_configuration(rk: RobotKinematics, rng: np.random.Generator) -> np.ndarray:
    """Uniform within the joint limits (margins 10 %), or, one time in three, a singular one:
    a random half of the joints at their neutral value (0: stretched limbs, aligned axes)."""
    model = rk.model
    q = pin.neutral(model)
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    for j in range(1, model.njoints):
        joint = model.joints[j]
        i, nq = joint.idx_q, joint.nq
        if nq == 1 and np.isfinite(lo[i]) and np.isfinite(hi[i]) and hi[i] - lo[i] < 50:
            q[i] = lo[i] + rng.uniform(0.1, 0.9) * (hi[i] - lo[i])
        elif nq == 1:
            q[i] = rng.uniform(-np.pi, np.pi)
        elif nq == 2:  # continuous joint: (cos, sin)
            a = rng.uniform(-np.pi, np.pi)
            q[i : i + 2] = np.cos(a), np.sin(a)
    if rk.base_dofs == 6:
        q[:3] = rng.normal(0.0, 0.1, 3)
        q[3:7] = pin.Quaternion(pin.exp3(rng.normal(0.0, 0.3, 3))).coeffs()
    elif rk.base_dofs == 3:
        a = rng.uniform(-np.pi, np.pi)
        q[:4] = rng.normal(0.0, 0.5), rng.normal(0.0, 0.5), np.cos(a), np.sin(a)
    if rng.random() < 1 / 3:
        neutral = pin.neutral(model)
        for j in rng.choice(np.arange(1, model.njoints), size=model.njoints // 2, replace=False):
            joint = model.joints[int(j)]
            if j == 1 and rk.base_dofs:
                continue
            q[joint.idx_q : joint.idx_q + joint.nq] = neutral[joint.idx_q : joint.idx_q + joint.nq]
    return q


class TaskPool:
    """Random tasks (dicts for solve_hierarchy) from a robot's kinematics at q."""

    def __init__(self, rk: RobotKinematics, q: np.ndarray, rng: np.random.Generator):
        self.rk, self.rng = rk, rng
        model = rk.model
        self.data = model.createData()
        pin.computeJointJacobians(model, self.data, q)
        pin.framesForwardKinematics(model, self.data, q)
        self.Jcom = pin.jacobianCenterOfMass(model, self.data, q)
        self.nv = model.nv
        self.made: list[dict] = []

    def frame_jacobian(self) -> np.ndarray:
        f = int(self.rng.choice(self.rk.frames))
        return pin.getFrameJacobian(self.rk.model, self.data, f, pin.LOCAL_WORLD_ALIGNED)

    def jacobian(self) -> tuple[np.ndarray, list[int] | None]:
        """Rows of one task kind, drawn; unit columns for joint rows."""
        rng, nv = self.rng, self.nv
        kind = rng.choice(["frame6", "position", "relative", "com", "joints", "partial", "mixed"])
        if kind == "frame6":
            return self.frame_jacobian(), None
        if kind == "position":
            return self.frame_jacobian()[:3], None
        if kind == "relative":
            return self.frame_jacobian() - self.frame_jacobian(), None
        if kind == "com":
            return self.Jcom.copy(), None
        if kind == "partial":
            J = self.frame_jacobian()
            return J[np.sort(rng.choice(6, size=int(rng.integers(1, 4)), replace=False))], None
        if kind == "mixed":  # rank-deficient: a frame's rows and combinations of them
            J = self.frame_jacobian()[:3]
            return np.vstack([J, rng.normal(size=(2, 3)) @ J]), None
        k = int(rng.integers(1, max(2, min(12, nv - self.rk.base_dofs))))
        columns = sorted(rng.choice(np.arange(self.rk.base_dofs, nv), size=k, replace=False))
        return np.eye(nv)[columns], [int(c) for c in columns]

    def equality(self) -> dict:
        if self.made and self.rng.random() < 0.15:  # a task repeated (target kept or changed)
            t = dict(self.made[int(self.rng.integers(len(self.made)))])
            if t.pop("inequality", False) or self.rng.random() < 0.5:  # a new target
                t["lower"] = self.rng.normal(0.0, 0.3, len(t["lower"]))
            t.pop("upper", None)
            self.made.append(t)
            return t
        J, cols = self.jacobian()
        t = {"jacobian": J, "lower": self.rng.normal(0.0, 0.3, J.shape[0])}
        if cols is not None:
            t["unit_columns"] = cols
        self.made.append(t)
        return t

    def inequality(self) -> dict:
        """A box on some rows: a random centre and half-width (sometimes 0 wide, sometimes one
        side infinite), so that it binds or not."""
        rng = self.rng
        J, cols = self.jacobian()
        k = J.shape[0]
        centre = rng.normal(0.0, 0.2, k)
        half = rng.uniform(0.0, 0.3, k) * (rng.random(k) < 0.9)
        lo, hi = centre - half, centre + half
        lo[rng.random(k) < 0.15] = -np.inf
        hi[rng.random(k) < 0.15] = np.inf
        t = {"jacobian": J, "lower": lo, "upper": hi, "inequality": True}
        if cols is not None:
            t["unit_columns"] = cols
        self.made.append(t)
        return t

    def joint_bounds(self, binding: bool) -> dict:
        """Velocity bounds on every joint (not the base), tight enough to bind or ±100."""
        rk, rng, nv = self.rk, self.rng, self.nv
        n = nv - rk.base_dofs
        if binding:
            lo, hi = -rng.uniform(0.02, 0.5, n), rng.uniform(0.02, 0.5, n)
        else:
            lo, hi = np.full(n, -100.0), np.full(n, 100.0)
        columns = list(range(rk.base_dofs, nv))
        return {
            "jacobian": np.eye(nv)[columns],
            "lower": lo,
            "upper": hi,
            "inequality": True,
            "unit_columns": columns,
        }


LEVEL_SHAPES = ("equality", "inequality", "mixed")


WELL_POSED_GAP = 1e-3


def well_posed(levels: list[list[dict]]) -> bool:
    """Whether every level's rows, projected onto the freedom the equality rows above leave,
    are either dependent (singular values <= RANK_TOLERANCE x scale: an exact singularity, a
    repeated task) or clearly independent (>= WELL_POSED_GAP x scale). In between, the undamped
    cascade amplifies rounding by 1 / σ (up to 1e9) and two exact implementations may disagree
    at any digit: that is the regime damping exists for, not a test of the algorithm."""
    nv = levels[0][0]["jacobian"].shape[1]
    N = np.eye(nv)
    for level in levels:
        A, _, C, _, _ = _split(level)
        for rows in (A, C):
            if rows.shape[0] == 0 or N.shape[1] == 0:
                continue
            scale = max(1.0, float(np.max(np.linalg.norm(rows, axis=1))))
            sv = np.linalg.svd(rows @ N, compute_uv=False)
            if np.any((sv > RANK_TOLERANCE * scale) & (sv < WELL_POSED_GAP * scale)):
                return False
        if A.shape[0] and N.shape[1]:
            scale = max(1.0, float(np.max(np.linalg.norm(A, axis=1))))
            null, _ = _null_space(A @ N, scale)
            N = N @ null
    return True


def random_stack(name: str, rng: np.random.Generator) -> tuple[list[list[dict]], list[str]]:
    """A random stack on robot `name`: 2–6 levels, each equality, inequality-only or mixed (any
    position, the last included), joint-velocity bounds at level 0 or not (binding or not).
    Returns the levels and their shapes."""
    rk = robot_kinematics(name)
    pool = TaskPool(rk, random_configuration(rk, rng), rng)
    levels, shapes = [], []
    bounds = rng.random()
    if bounds < 0.6:
        levels.append([pool.joint_bounds(binding=bounds < 0.45)])
        shapes.append("bounds")
    for _ in range(int(rng.integers(2, 6))):
        shape = str(rng.choice(LEVEL_SHAPES, p=[0.5, 0.25, 0.25]))
        level = []
        if shape in ("equality", "mixed"):
            level += [pool.equality() for _ in range(int(rng.integers(1, 3)))]
        if shape in ("inequality", "mixed"):
            level += [pool.inequality() for _ in range(int(rng.integers(1, 3)))]
        rng.shuffle(level)
        levels.append(level)
        shapes.append(shape)
    return levels, shapes


def perturbed(levels: list[list[dict]], rng: np.random.Generator) -> list[list[dict]]:
    """The same stack (shapes, Jacobians) with every target and bound moved by N(0, 0.05): the
    next tick of a controller, whose QP levels start from the last tick's working set."""
    out = []
    for level in levels:
        moved = []
        for task in level:
            task = dict(task)
            shift = rng.normal(0.0, 0.05, len(task["lower"]))
            task["lower"] = task["lower"] + shift
            if task.get("inequality"):
                task["upper"] = task["upper"] + shift
            moved.append(task)
        out.append(moved)
    return out
