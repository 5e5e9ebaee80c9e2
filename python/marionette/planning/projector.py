"""Newton-Raphson projection onto numerical constraints (thesis Algorithm 1, §3.2.2).

``Projector(problem, constraints)`` compiles a set of constraints once:

* explicit constraints are *substituted* (HPP's solver "by substitution"): locked joints are
  written, then grasped objects get their pose from the gripper pose, so a grasp state needs no
  iteration at all;  an explicit constraint whose output is already determined by another one
  (grasp + object locked on the table in the "intersection" waypoint) becomes implicit;
* a :class:`Placement` and its :class:`PlacementComplement` on the same object (object held
  still on its surface) merge into a locked object joint, as HPP merges a constraint with its
  complement;
* the remaining implicit constraints are solved by Newton-Raphson on the free variables with
  the chain rule through the substituted ones,
  q <- q (+) -alpha J_red^+ e   (Algorithm 1; J_red = J_free + J_out Ad J_parent),
  with priority levels (each solved in the null space of the previous ones), joint bounds
  (clamping, saturated directions removed), a step-size schedule and an iteration limit.

:meth:`Projector.project` returns a :class:`ProjectionResult` telling why it failed when it does.

``backend="cpp"`` (default) runs the Newton loop of a compiled projector in C++
(``projector_cpp.py``, ``cpp/src/planning/projector.cc``): same steps, schedule, limits and
failure reasons.  A projector with a constraint kind the C++ side lacks (centre of mass) stays
in Python, decided once when it is built (``backend`` then reads "python" and
``fallback_reason`` says why).  ``backend="python"`` is the reference implementation.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from marionette.planning.constraints import (
    Constraint,
    ConstraintError,
    ExplicitConstraint,
    ExplicitRelativePose,
    Kinematics,
    LockedJoint,
    Placement,
    PlacementComplement,
)
from marionette.planning.problem import ManipulationProblem


class ProjectionStatus(enum.Enum):
    SUCCESS = "success"
    MAX_ITERATIONS = "iteration limit reached"
    NOT_DECREASING = "error stopped decreasing (3 iterations in a row)"
    LOCAL_MINIMUM = "step vanished before the error did (singular or unreachable)"
    NOT_FINITE = "configuration or error is not finite (NaN or inf)"


@dataclasses.dataclass
class ProjectionResult:
    """Outcome of a projection: ``success``, ``status`` (why not), iterations, final error norm."""

    status: ProjectionStatus
    iterations: int
    error_norm: float

    @property
    def success(self) -> bool:
        return self.status is ProjectionStatus.SUCCESS

    def __bool__(self) -> bool:
        return self.success

    def __str__(self) -> str:
        return (
            f"{self.status.value} after {self.iterations} iterations, |e| = {self.error_norm:.3g}"
        )


@dataclasses.dataclass(frozen=True)
class LineSearch:
    """Step-size schedule.

    ``fixed_sequence`` is Algorithm 1: alpha starts at ``alpha0`` and
    alpha <- alpha_max - K (alpha_max - alpha) (thesis: alpha0 = .1, alpha_max = .95, K = .8).
    ``error_norm`` is HPP's ErrorNormBased: alpha = C - K tanh(a r + b), r = |e|^2 / eps^2, from
    ``alpha_min`` far from the manifold to 1 (pure Newton) close to it.  ``constant``: alpha = 1.
    ``max_step`` bounds |dq| of one iteration (a trust region; inf = none).

    The default (full Newton steps within a 1-rad trust region) is the fastest on the arm
    pick-and-place benchmark (bench/ur5_box): 6-D pre-grasp IK from uniform samples succeeds
    40 % of the time in a median of 9 iterations, against 23 % in 11 for Algorithm 1's schedule
    (tests/python/planning).
    """

    kind: str = "constant"
    alpha0: float = 0.1
    alpha_max: float = 0.95
    K: float = 0.8
    alpha_min: float = 0.2
    max_step: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in ("fixed_sequence", "error_norm", "constant"):
            raise ValueError(
                f"line search kind must be fixed_sequence, error_norm or constant, "
                f"got {self.kind!r}"
            )


ALGORITHM_1 = LineSearch("fixed_sequence", alpha0=0.1, alpha_max=0.95, K=0.8, max_step=math.inf)


class Projector:
    """Projector onto a set of constraints (thesis Definition 4: f(p(q)) = 0, p(p(q)) = p(q)).

    ``constraints``: implicit :class:`Constraint` and :class:`ExplicitConstraint` objects;
    ``levels``: priority of each implicit constraint (0 = highest), default all 0.
    The projector owns its :class:`Kinematics` workspace (one projector per thread).
    """

    def __init__(
        self,
        problem: ManipulationProblem,
        constraints: Sequence[Constraint | ExplicitConstraint],
        levels: Sequence[int] | None = None,
        error_threshold: float = 1e-4,
        max_iterations: int = 40,
        line_search: LineSearch = LineSearch(),
        damping: float = 1e-8,
        name: str = "",
        backend: str = "cpp",
    ) -> None:
        if backend not in ("cpp", "python"):
            raise ValueError(f"projector backend must be 'cpp' or 'python', got {backend!r}")
        if error_threshold <= 0:
            raise ValueError(f"error_threshold must be > 0, got {error_threshold}")
        if max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
        self.problem = problem
        self.model = problem.model
        self.name = name
        self.kin = Kinematics(problem.model)
        self.error_threshold = error_threshold
        self.max_iterations = max_iterations
        self.line_search = line_search
        self.damping = damping
        self.max_step = line_search.max_step
        self.constraints = list(constraints)
        lv = list(levels) if levels is not None else None
        self._compile(lv)
        self.fallback_reason: str | None = None
        self._cpp = None
        if backend == "cpp":
            from marionette.planning import projector_cpp

            self.fallback_reason = projector_cpp.unsupported(self)
            if self.fallback_reason is None:
                self._cpp = projector_cpp.CppProjector(self)
        self.backend = "cpp" if self._cpp is not None else "python"

    # ----------------------------------------------------------------------------- compilation
    def _compile(self, levels: list[int] | None) -> None:
        model = self.model
        implicit: list[tuple[Constraint, int]] = []
        explicit: list[ExplicitConstraint] = []
        k = 0
        for c in self.constraints:
            if isinstance(c, ExplicitConstraint):
                explicit.append(c)
            elif isinstance(c, Constraint):
                implicit.append((c, levels[k] if levels else 0))
                k += 1
            else:
                raise ConstraintError(f"not a constraint: {c!r}")
        if levels is not None and len(levels) != k:
            raise ValueError(f"{len(levels)} levels for {k} implicit constraints")

        # Placement + complement of one object -> the object is locked where it is.
        self._merged: list[tuple[LockedJoint, Placement]] = []
        placements = {c.object: c for c, _ in implicit if isinstance(c, Placement)}
        complements = {
            c.placement.object: c for c, _ in implicit if isinstance(c, PlacementComplement)
        }
        for obj, comp in complements.items():
            plc = comp.placement
            if placements.get(obj) is plc:
                info = self.problem.objects[obj]
                lock = LockedJoint(f"{plc.name}/hold", model, info.joint_id)
                self._merged.append((lock, plc))
                implicit = [(c, lv) for c, lv in implicit if c is not plc and c is not comp]
                explicit.insert(0, lock)

        # Substitution order: locked joints, then relative poses; a second explicit constraint
        # on an already determined joint, or one whose parent is determined by substitution,
        # becomes implicit.
        explicit.sort(key=lambda e: 0 if isinstance(e, LockedJoint) else 1)
        determined: set[int] = set()
        self.locked: list[LockedJoint] = []
        self.relative: list[ExplicitRelativePose] = []
        for e in explicit:
            chain = set(_ancestors(model, next(iter(e.input_joints()))) if e.input_joints() else [])
            if e.output_joint in determined or (chain & determined):
                implicit.append((e.as_implicit(), 0))
                continue
            determined.add(e.output_joint)
            if isinstance(e, LockedJoint):
                self.locked.append(e)
            elif isinstance(e, ExplicitRelativePose):
                self.relative.append(e)
            else:
                raise TypeError(
                    f"explicit constraint {e.name}: {type(e).__name__} is neither a LockedJoint "
                    "nor an ExplicitRelativePose, the two kinds the projector substitutes"
                )

        self.implicit = [c for c, _ in implicit]
        lv = sorted({lv for _, lv in implicit})
        self.levels = [[c for c, l in implicit if l == L] for L in lv]
        free = np.ones(model.nv, dtype=bool)
        for j in determined:
            free[model.idx_vs[j] : model.idx_vs[j] + model.joints[j].nv] = False
        self.free = free
        self.free_idx = np.flatnonzero(free)
        self.output_joints = determined
        self.placements = [c for c in self.implicit if isinstance(c, Placement)]
        self._free_placements = [
            p
            for p in self.placements
            if not any(
                isinstance(c, PlacementComplement) and c.placement is p for c in self.implicit
            )
        ]
        self.parametrised = [c for c in self.implicit if c.parametrised]
        # q entries clamped to the bounds: all but quaternions.
        bounded = np.ones(model.nq, dtype=bool)
        for i in self.problem.freeflyer_idx_q:
            bounded[i + 3 : i + 7] = False
        self._bounded = np.flatnonzero(bounded)
        self._lower = self.problem.lower[self._bounded]
        self._upper = self.problem.upper[self._bounded]
        # v index of each bounded 1-dof q entry (for saturation); free-flyer translations are
        # handled by clamping only.
        pos = {v: k for k, v in enumerate(self.free_idx)}
        self._sat_cols = []  # (column in the free variables, q index) of 1-dof joints
        for jid in range(1, model.njoints):
            if model.joints[jid].nq == 1 and model.joints[jid].nv == 1:
                iv = model.idx_vs[jid]
                if iv in pos:
                    self._sat_cols.append((pos[iv], model.idx_qs[jid]))
        self.size = sum(c.size for c in self.implicit)
        self._dv = np.zeros(model.nv)
        self._clipped = True
        self._sat_k = np.array([k for k, _ in self._sat_cols], dtype=int)
        self._sat_q = np.array([iq for _, iq in self._sat_cols], dtype=int)
        self._sat_lo = self.problem.lower[self._sat_q]
        self._sat_hi = self.problem.upper[self._sat_q]
        # Relative explicit outputs that are leaf free-flyers under the universe: substituted
        # after a single forward kinematics by patching their pose (no second FK pass).
        children = set(model.parents[1:])
        self._patchable = all(
            model.parents[e.output_joint] == 0 and e.output_joint not in children
            for e in self.relative
        )
        # Locked leaves under the universe (objects held still) never move while projecting;
        # a locked joint deeper in a chain (a finger) still moves with its parent.
        self.kin.static = frozenset(
            lk.output_joint
            for lk in self.locked
            if lk.output_joint not in children and model.parents[lk.output_joint] == 0
        )

    # ----------------------------------------------------------------------------- rhs
    def set_rhs_from(self, q: np.ndarray) -> None:
        """Right-hand sides of the parametrised constraints (and locked values) from q."""
        for lk in self.locked:
            if lk.parametrised:
                lk.rhs_from_q(q)
        if self.parametrised or self._merged:
            self.kin.update(q, jacobians=False)
            for c in self.parametrised:
                if isinstance(c, PlacementComplement):
                    c.placement.select_pair(self.kin)
                c.rhs = c.rhs_from(self.kin)

    def set_rhs_of(
        self, constraints: Sequence[Constraint | ExplicitConstraint], q: np.ndarray
    ) -> None:
        """Right-hand sides of some parametrised ``constraints`` from q (the others unchanged): a
        placement complement merged with its placement sets the locked object pose."""
        wanted = {id(c) for c in constraints}
        for lk, plc in self._merged:
            comp = next((c for c in constraints if getattr(c, "placement", None) is plc), None)
            if comp is not None:
                lk.rhs_from_q(q)
                wanted.discard(id(comp))
        for lk in self.locked:
            if id(lk) in wanted:
                lk.rhs_from_q(q)
        todo = [c for c in self.parametrised if id(c) in wanted]
        if todo:
            self.kin.update(q, jacobians=False)
            for c in todo:
                if isinstance(c, PlacementComplement):
                    c.placement.select_pair(self.kin)
                c.rhs = c.rhs_from(self.kin)

    def rhs_state(self) -> tuple:
        """Snapshot of every right-hand side (restore it with :meth:`restore_rhs`)."""
        return (
            tuple(lk.value.copy() for lk in self.locked),
            tuple(c.rhs.copy() for c in self.parametrised),
            tuple(p.pair for p in self.placements),
        )

    def restore_rhs(self, state: tuple) -> None:
        for lk, v in zip(self.locked, state[0]):
            lk.value = v
        for c, v in zip(self.parametrised, state[1]):
            c.rhs = v
        for p, v in zip(self.placements, state[2]):
            p.pair = v

    def rhs_vector(self) -> dict[str, list[float]]:
        """The current right-hand sides by constraint name (for the plan file)."""
        out = {lk.name: lk.value.tolist() for lk in self.locked}
        out.update({c.name: c.rhs.tolist() for c in self.implicit})
        return out

    # ----------------------------------------------------------------------------- evaluation
    def apply_explicit(self, q: np.ndarray) -> None:
        """Substitute the explicit constraints into q (in place); leaves FK of q in ``kin``."""
        for lk in self.locked:
            lk.apply(self.kin, q)
        if self.relative:
            self.kin.update(q, jacobians=False)
            for e in self.relative:
                e.apply(self.kin, q)

    def _errors(self, level: list[Constraint]) -> np.ndarray:
        if len(level) == 1:
            return level[0].compute_error(self.kin)
        return np.concatenate([c.compute_error(self.kin) for c in level]) if level else np.zeros(0)

    def error(self, q: np.ndarray) -> np.ndarray:
        """Stacked implicit errors at q (explicit ones are satisfied by substitution)."""
        self.kin.update(q, jacobians=False)
        self._select_pairs()
        return self._errors(self.implicit)

    def _select_pairs(self) -> None:
        """Placements not pinned by a complement take the surface pair nearest to q."""
        for p in self._free_placements:
            p.select_pair(self.kin)

    def explicit_error(self, q: np.ndarray) -> float:
        """How far q is from the explicit constraints (0 after :meth:`apply_explicit`)."""
        err = 0.0
        for lk in self.locked:
            err = max(err, lk.error(q))
        if self.relative:
            self.kin.update(q, jacobians=False)
            for e in self.relative:
                X = pin.XYZQUATToSE3(q[e.idx_q : e.idx_q + 7])
                err = max(err, float(np.linalg.norm(pin.log6(e.pose(self.kin).actInv(X)).vector)))
        return err

    def is_satisfied(self, q: np.ndarray, threshold: float | None = None) -> bool:
        """Do q satisfy every constraint (explicit ones too) within ``threshold``?"""
        th = self.error_threshold if threshold is None else threshold
        if self._cpp is not None:
            return self._cpp.is_satisfied(q, th)
        if self.explicit_error(q) > th:
            return False
        if not self.implicit:
            return True
        e = self.error(q)
        return bool(e.dot(e) <= th * th)

    def _reduced_jacobian(self, level: list[Constraint]) -> np.ndarray:
        J = (
            level[0].compute_jacobian(self.kin)
            if len(level) == 1
            else np.vstack([c.compute_jacobian(self.kin) for c in level])
        )
        for e in self.relative:
            Jo = J[:, e.idx_v : e.idx_v + 6]
            if np.any(Jo):
                J += Jo @ (e.Ad_OP @ self.kin.joint_jacobian(e.parent_joint))
        return J if len(self.free_idx) == J.shape[1] else J[:, self.free_idx]

    # ----------------------------------------------------------------------------- projection
    def project(self, q: np.ndarray) -> ProjectionResult:
        """Project q (nq, modified in place) onto the constraints."""
        if self._cpp is not None:
            code, it, err = self._cpp.project(q, self.error_threshold, self.max_iterations)
            return ProjectionResult(_STATUS[code], it, err)
        return self._project_python(q)

    def _project_python(self, q: np.ndarray) -> ProjectionResult:
        """The reference implementation of :meth:`project` (Algorithm 1)."""
        if not self.implicit:
            self.apply_explicit(q)
            return ProjectionResult(ProjectionStatus.SUCCESS, 0, 0.0)
        kin, model = self.kin, self.model
        for lk in self.locked:
            lk.apply(kin, q)
        self._update_and_substitute(q)
        self._select_pairs()
        eps2 = self.error_threshold**2
        levels = self.levels
        errors = [self._errors(L) for L in levels]
        norm2 = _norm2(errors)
        if not math.isfinite(norm2):
            return ProjectionResult(ProjectionStatus.NOT_FINITE, 0, norm2)
        alpha = self.line_search.alpha0
        not_decreasing = 0
        dv = self._dv
        free_idx = self.free_idx
        all_free = len(free_idx) == model.nv
        lower, upper, bounded = self._lower, self._upper, self._bounded
        max_step2 = self.max_step**2
        self._clipped = True  # unknown at the start: check the bounds once
        it = 0
        while norm2 > eps2:
            if it >= self.max_iterations:
                return ProjectionResult(ProjectionStatus.MAX_ITERATIONS, it, math.sqrt(norm2))
            step = self._descent(errors, q)
            n2 = step.dot(step)
            if n2 < 1e-20:
                return ProjectionResult(ProjectionStatus.LOCAL_MINIMUM, it, math.sqrt(norm2))
            if n2 > max_step2:
                # Trust region: far from the manifold, the linearisation is wrong anyway.
                step *= self.max_step / math.sqrt(n2)
            ls = self.line_search
            if ls.kind == "fixed_sequence":
                a = alpha
                alpha = ls.alpha_max - ls.K * (ls.alpha_max - alpha)
            elif ls.kind == "error_norm":
                a = _error_norm_alpha(norm2 / eps2, ls.alpha_min)
            else:
                a = 1.0
            if a != 1.0:
                step *= a
            if all_free:
                q[:] = pin.integrate(model, q, step)
            else:
                dv[free_idx] = step
                q[:] = pin.integrate(model, q, dv)
            qb = q[bounded]
            self._clipped = bool(((qb < lower) | (qb > upper)).any())
            if self._clipped:
                q[bounded] = np.clip(qb, lower, upper)
            self._update_and_substitute(q)
            errors = [self._errors(L) for L in levels]
            new_norm2 = _norm2(errors)
            if not math.isfinite(new_norm2):
                return ProjectionResult(ProjectionStatus.NOT_FINITE, it, new_norm2)
            it += 1
            not_decreasing = not_decreasing + 1 if new_norm2 >= norm2 else 0
            norm2 = new_norm2
            if not_decreasing >= 3 and norm2 > eps2:
                return ProjectionResult(ProjectionStatus.NOT_DECREASING, it, math.sqrt(norm2))
        return ProjectionResult(ProjectionStatus.SUCCESS, it, math.sqrt(norm2))

    def _descent(self, errors: list[np.ndarray], q: np.ndarray) -> np.ndarray:
        """Newton step on the free variables, level by level, saturated joints removed."""
        jacobians = [self._reduced_jacobian(L) for L in self.levels]
        sat: Sequence[int] = ()
        # A joint can only sit on a bound after a clipped step (or at the start).
        if self._sat_k.size and self._clipped:
            # HPP's saturation: a joint on a bound whose gradient descent direction -J^T e
            # points outward is removed from the problem (one solve, no retry).
            qs = q[self._sat_q]
            at_lo = qs <= self._sat_lo
            at_hi = qs >= self._sat_hi
            if (at_lo | at_hi).any():
                d = -(jacobians[0].T @ errors[0])[self._sat_k]
                out = (at_lo & (d < 0)) | (at_hi & (d > 0))
                if out.any():
                    sat = self._sat_k[out]
        return self._solve(jacobians, errors, sat)

    def _update_and_substitute(self, q: np.ndarray) -> None:
        """Forward kinematics + Jacobians at q with the explicit outputs substituted."""
        if self.relative and self._patchable:
            kin = self.kin
            kin.update(q)
            for e in self.relative:
                X = e.pose(kin)
                q[e.idx_q : e.idx_q + 7] = pin.SE3ToXYZQUAT(X)
                kin.set_joint_placement(e.output_joint, X)
        else:
            self.apply_explicit(q)
            self.kin.update(q)

    def _solve(
        self, jacobians: list[np.ndarray], errors: list[np.ndarray], sat: Sequence[int]
    ) -> np.ndarray:
        if len(jacobians) == 1:
            J = jacobians[0]
            if len(sat):
                J = J.copy()
                J[:, sat] = 0.0
            AAt = J @ J.T
            AAt.flat[:: AAt.shape[0] + 1] += self.damping
            _, x, info = lapack.dposv(AAt, errors[0])
            if info != 0:
                x = np.linalg.lstsq(AAt, errors[0], rcond=None)[0]
            return -(J.T @ x)
        n = len(self.free_idx)
        step = np.zeros(n)
        N = None
        for J, e in zip(jacobians, errors):
            if len(sat):
                J = J.copy()
                J[:, list(sat)] = 0.0
            r = -e - J @ step if N is not None else -e
            A = J if N is None else J @ N
            # Damped least squares: A^T (A A^T + lambda I)^-1 r (lambda tiny: Newton near the
            # solution, bounded steps near singularities); Cholesky through LAPACK directly,
            # numpy.linalg.solve costs 10x more on these small systems.
            AAt = A @ A.T
            AAt.flat[:: AAt.shape[0] + 1] += self.damping
            _, x, info = lapack.dposv(AAt, r)
            if info != 0:
                x = np.linalg.lstsq(AAt, r, rcond=None)[0]
            step = step + A.T @ x
            if len(jacobians) > 1:
                P = np.linalg.pinv(A, rcond=1e-8) @ A
                N = (np.eye(n) - P) if N is None else N @ (np.eye(n) - P)
        return step


# C++ status codes (ProjectionStatus in cpp/include/marionette/planning/projector.h).
_STATUS = (
    ProjectionStatus.SUCCESS,
    ProjectionStatus.MAX_ITERATIONS,
    ProjectionStatus.NOT_DECREASING,
    ProjectionStatus.LOCAL_MINIMUM,
    ProjectionStatus.NOT_FINITE,
)


def _norm2(errors: list[np.ndarray]) -> float:
    if len(errors) == 1:
        e = errors[0]
        return float(e.dot(e))
    return sum(float(e.dot(e)) for e in errors)


def _error_norm_alpha(r: float, alpha_min: float) -> float:
    # HPP ErrorNormBased: alpha = C - K tanh(a r + b), alpha(r >> r_half) -> alpha_min,
    # alpha(r ~ 0) ~ 1 - delta, with r_half = 1e6, delta = 0.02.
    C = 0.5 + alpha_min / 2
    K = (1 - alpha_min) / 2
    a = math.atanh((0.02 - 1 + C) / K) / (1 - 1e6)
    b = -1e6 * a
    return C - K * math.tanh(a * r + b)


def _ancestors(model: pin.Model, joint: int) -> list[int]:
    out = []
    while joint > 0:
        out.append(joint)
        joint = model.parents[joint]
    return out
