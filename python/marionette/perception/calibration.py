"""Calibration tools: hand-eye (thesis 001 §4.3, Tsai-Lenz) and joint offsets (thesis 000 §4.2).

**Hand-eye.** Dang's HRP-2 setting: a target (chessboard, tag) fixed in the hand H is observed by
a camera C in the head G; the pairs (X_GH_i by kinematics, X_CT_i by vision) give the mount
X_GC. Seen from the target, the camera moves on a robot whose base is the hand: the classical
eye-in-hand problem A X = X B (eq. 4.4-4.6) with X_RE_i = X_HG_i = X_GH_i^-1, solved by ViSP's
vpHandEyeCalibration (Tsai-Lenz closed form + non-linear refinement).

**Joint offsets.** Nicolin's first method (§4.2): each revolute joint j reads q_j but sits at
q_j + delta_j. Markers on a base link B (the chest) and an end link E (the gripper) are measured
(MoCap, or a tag seen by the head camera) in many configurations q_i. The unknowns shared by all
measurements are the offsets delta, the marker's position p_EM in E and the base marker's p_BA
in B; each measurement i gives three equations

    r_i = X_BE(q_i + S delta) p_EM - p_BA - m_i = 0,

and all configurations are projected at once: a Levenberg-Marquardt (damped Gauss-Newton) on the
stacked residuals, "analogous to a least mean squares method" as §4.2 puts it. The Jacobian
columns are Pinocchio's frame Jacobians (checked against finite differences in the tests).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, overload

import numpy as np
import pinocchio as pin


class CalibrationError(ValueError):
    """Calibration input is inconsistent or the problem is not observable; says which."""


# ---- hand-eye --------------------------------------------------------------------------------


@dataclass(frozen=True)
class HandEye:
    X_EC: pin.SE3  # effector <- camera
    X_RT: pin.SE3  # base <- target (mean over the pairs)
    rms_position: float  # [m] spread of X_RE_i X_EC X_CT_i
    rms_rotation: float  # [rad]


def calibrate_hand_eye(X_RE: Sequence[pin.SE3], X_CT: Sequence[pin.SE3]) -> HandEye:
    """Eye-in-hand: X_EC such that X_RE_i X_EC X_CT_i is constant (needs >= 3 pairs whose
    effector rotations span two non-parallel axes)."""
    from marionette import _visp

    try:
        r = _visp.calibrate_hand_eye([X.homogeneous for X in X_RE], [X.homogeneous for X in X_CT])
    except ValueError as exc:
        raise CalibrationError(str(exc)) from None
    return HandEye(pin.SE3(r.X_EC), pin.SE3(r.X_RT), r.rms_position, r.rms_rotation)


def calibrate_head_camera(X_GH: Sequence[pin.SE3], X_CT: Sequence[pin.SE3]) -> HandEye:
    """Thesis 001 §4.3: camera C on the head G, target T on the hand H. Returns X_GC (as
    ``X_EC``) and the target's pose in the hand X_HT (as ``X_RT``)."""
    return calibrate_hand_eye([X.inverse() for X in X_GH], X_CT)


# ---- joint offsets ---------------------------------------------------------------------------


@dataclass(frozen=True)
class JointOffsetProblem:
    """Marker positions of ``marker_frame`` measured relative to ``base_frame``; offsets
    sought on ``joints`` (revolute or prismatic, 1 dof each)."""

    model: pin.Model
    base_frame: str
    marker_frame: str
    joints: tuple[str, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "joints", tuple(self.joints))
        for frame in (self.base_frame, self.marker_frame):
            if not self.model.existFrame(frame):
                raise CalibrationError(f"model {self.model.name} has no frame {frame!r}")
        if not self.joints:
            raise CalibrationError("no joints to calibrate")
        for name in self.joints:
            if (
                not self.model.existJointName(name)
                or self.model.joints[self.model.getJointId(name)].nq != 1
            ):
                raise CalibrationError(f"{name!r} is not a 1-dof joint of {self.model.name}")
        if len(set(self.joints)) != len(self.joints):
            raise CalibrationError(f"joints listed twice: {self.joints}")

    @property
    def idx_q(self) -> np.ndarray:
        return np.array([self.model.joints[self.model.getJointId(n)].idx_q for n in self.joints])

    @property
    def idx_v(self) -> np.ndarray:
        return np.array([self.model.joints[self.model.getJointId(n)].idx_v for n in self.joints])

    @property
    def num_unknowns(self) -> int:
        return len(self.joints) + 6


@dataclass(frozen=True)
class JointOffsetResult:
    offsets: np.ndarray  # (k,) [rad] true angle = encoder reading + offset
    p_EM: np.ndarray  # (3,) marker in the marker frame [m]
    p_BA: np.ndarray  # (3,) base marker in the base frame [m]
    rms_residual: float  # [m] per coordinate at the solution
    offsets_std: np.ndarray  # (k,) [rad] 1-sigma from the residual and J^T J
    iterations: int


def marker_positions(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    offsets: np.ndarray,
    p_EM: np.ndarray,
    p_BA: np.ndarray,
) -> np.ndarray:
    """(N, 3) predicted measurements X_BE(q_i + S offsets) p_EM - p_BA for encoder readings
    Q (N, nq) (also how tests simulate a miscalibrated robot)."""
    return _residuals(problem, Q, np.zeros((len(Q), 3)), _pack(offsets, p_EM, p_BA), False)[
        0
    ].reshape(-1, 3)


def _pack(offsets, p_EM, p_BA) -> np.ndarray:
    return np.concatenate(
        [np.asarray(offsets, float), np.asarray(p_EM, float), np.asarray(p_BA, float)]
    )


@overload
def _residuals(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: np.ndarray,
    x: np.ndarray,
    with_jacobian: Literal[True] = True,
) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def _residuals(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: np.ndarray,
    x: np.ndarray,
    with_jacobian: Literal[False],
) -> tuple[np.ndarray, None]: ...
def _residuals(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: np.ndarray,
    x: np.ndarray,
    with_jacobian: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Stacked r (3N,) and dr/dx (3N, k + 6) at x = (offsets, p_EM, p_BA)."""
    model = problem.model
    data = model.createData()
    k = len(problem.joints)
    offsets, p_EM, p_BA = x[:k], x[k : k + 3], x[k + 3 :]
    b = model.getFrameId(problem.base_frame)
    e = model.getFrameId(problem.marker_frame)
    iq, iv = problem.idx_q, problem.idx_v
    r = np.empty(3 * len(Q))
    J = np.zeros((3 * len(Q), k + 6)) if with_jacobian else None
    for i, q in enumerate(Q):
        q = np.array(q, dtype=float)
        q[iq] += offsets
        pin.forwardKinematics(model, data, q)
        X_WB = pin.updateFramePlacement(model, data, b)
        X_WE = pin.updateFramePlacement(model, data, e)
        R_WB = X_WB.rotation
        p_WM = X_WE.act(p_EM)
        r[3 * i : 3 * i + 3] = R_WB.T @ (p_WM - X_WB.translation) - p_BA - measured[i]
        if J is None:
            continue
        pin.computeJointJacobians(model, data, q)
        J_E = pin.getFrameJacobian(model, data, e, pin.LOCAL_WORLD_ALIGNED)
        J_B = pin.getFrameJacobian(model, data, b, pin.LOCAL_WORLD_ALIGNED)
        arm = X_WE.rotation @ p_EM  # from E's origin to M, world axes
        J_M = J_E[:3] - pin.skew(arm) @ J_E[3:]  # velocity of the point M
        x_BM = p_WM - X_WB.translation
        # d/dt (R_WB^T x) = R_WB^T (x' - w_B x x) = R_WB^T (x' + [x]x w_B)
        J_q = R_WB.T @ (J_M - J_B[:3] + pin.skew(x_BM) @ J_B[3:])
        J[3 * i : 3 * i + 3, :k] = J_q[:, iv]
        J[3 * i : 3 * i + 3, k : k + 3] = R_WB.T @ X_WE.rotation
        J[3 * i : 3 * i + 3, k + 3 :] = -np.eye(3)
    return r, J


def residuals_and_jacobian(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: np.ndarray,
    offsets: np.ndarray,
    p_EM: np.ndarray,
    p_BA: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Stacked residuals (3N,) and their Jacobian (3N, k + 6) w.r.t. (offsets, p_EM, p_BA)."""
    return _residuals(
        problem, np.asarray(Q, float), np.asarray(measured, float), _pack(offsets, p_EM, p_BA)
    )


def _check_observable(problem: JointOffsetProblem, J: np.ndarray) -> None:
    """Raises when J (3N, k + 6) has a null direction, naming the unknowns it mixes.

    A classic case: with position-only measurements, an offset of the joint right before the
    marker frame is the same as turning p_EM about that joint's axis; calibrate that joint
    with orientation measurements or leave it out (its offset is then absorbed by p_EM).
    """
    _, singular, Vt = np.linalg.svd(J, full_matrices=False)
    if singular[-1] >= 1e-9 * singular[0]:
        return
    names = [
        *(f"offset {j}" for j in problem.joints),
        "p_EM.x",
        "p_EM.y",
        "p_EM.z",
        "p_BA.x",
        "p_BA.y",
        "p_BA.z",
    ]
    mixed = [names[i] for i in np.flatnonzero(np.abs(Vt[-1]) > 0.1)]
    raise CalibrationError(
        f"unknowns not observable from these measurements: {', '.join(mixed)} can change "
        "together without changing any marker position; vary every calibrated joint, and do "
        "not calibrate the joint just before the marker frame from positions alone"
    )


def calibrate_joint_offsets(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: np.ndarray,
    offsets0: np.ndarray | None = None,
    p_EM0: np.ndarray | None = None,
    p_BA0: np.ndarray | None = None,
    max_iterations: int = 100,
    tolerance: float = 1e-12,
) -> JointOffsetResult:
    """Offsets, marker positions from encoder readings Q (N, nq) and measured marker positions
    (N, 3) in the base frame: all configurations projected at once (Levenberg-Marquardt).

    Raises :class:`CalibrationError` when shapes disagree, when there are fewer equations than
    unknowns, or when the configurations do not make every unknown observable.
    """
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    measured = np.atleast_2d(np.asarray(measured, dtype=float))
    if Q.shape[1] != problem.model.nq or measured.shape != (len(Q), 3):
        raise CalibrationError(
            f"need Q (N, {problem.model.nq}) and measured (N, 3), got "
            f"{Q.shape} and {measured.shape}"
        )
    if not (np.all(np.isfinite(Q)) and np.all(np.isfinite(measured))):
        raise CalibrationError("configurations and measurements must be finite")
    n = problem.num_unknowns
    if 3 * len(Q) < n:
        raise CalibrationError(
            f"{len(Q)} measurements give {3 * len(Q)} equations for {n} unknowns"
        )
    k = len(problem.joints)
    x = _pack(
        np.zeros(k) if offsets0 is None else offsets0,
        np.zeros(3) if p_EM0 is None else p_EM0,
        np.zeros(3) if p_BA0 is None else p_BA0,
    )
    r, J = _residuals(problem, Q, measured, x)
    # No observability check here: the initial guess may be degenerate (a marker guessed at
    # the wrist centre hides the wrist offsets); the check runs at the solution.
    damping = 1e-3
    cost = r @ r
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (read after the loop)
        H = J.T @ J
        g = J.T @ r
        # Marquardt scaling, floored so that columns still zero at the guess stay solvable.
        scale = np.diag(H) + 1e-9 * np.trace(H) / len(H)
        step = -np.linalg.solve(H + damping * np.diag(scale), g)
        x_new = x + step
        r_new, J_new = _residuals(problem, Q, measured, x_new)
        cost_new = r_new @ r_new
        if cost_new < cost:
            x, r, J, cost = x_new, r_new, J_new, cost_new
            damping = max(damping / 10, 1e-12)
            if np.linalg.norm(step) < 1e-12 or cost < tolerance:
                break
        else:
            damping *= 10
            if damping > 1e8:
                break
    _check_observable(problem, J)
    dof = max(1, len(r) - n)
    sigma2 = cost / dof
    covariance = sigma2 * np.linalg.inv(J.T @ J)
    return JointOffsetResult(
        offsets=x[:k],
        p_EM=x[k : k + 3],
        p_BA=x[k + 3 :],
        rms_residual=float(np.sqrt(cost / len(r))),
        offsets_std=np.sqrt(np.diag(covariance)[:k]),
        iterations=iterations,
    )


# ---- joint offsets from marker poses ---------------------------------------------------------
#
# §4.2 with a camera instead of MoCap: a tag body on the end link E gives its full pose in the
# camera, and the camera's pose in the base link B comes from joints the calibration does not
# touch (a humanoid's head above its arms), so each view i measures M_i = X_BE directly and the
# marker's placement in E is known (the model's tags). The residual is the pose error
#
#     r_i(delta) = W log6( M_i^-1 X_BE(q_i + S delta) ),   W = diag(1, 1, 1, w, w, w)
#
# with w [m/rad] weighing rotation against translation, and every joint of the chain, the last
# included, is observable from rotations. dr/ddelta = W Jlog6 J_E(q_i + S delta)[:, S] (J_E the
# frame Jacobian of E in its own frame; B does not depend on the calibrated joints).


@dataclass(frozen=True)
class PoseOffsetResult:
    offsets: np.ndarray  # (k,) [rad] true angle = encoder reading + offset
    offsets_std: np.ndarray  # (k,) [rad] 1-sigma from the residual and J^T J
    position_residuals: np.ndarray  # (N,) [m] per view at the solution
    rotation_residuals: np.ndarray  # (N,) [rad] per view at the solution
    outliers: tuple[int, ...] = ()  # views left out of the final solve


def pose_residuals_and_jacobian(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: Sequence[pin.SE3],
    offsets: np.ndarray,
    rotation_weight: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Stacked r (6N,) and dr/doffsets (6N, k) of the pose residuals above."""
    model, data = problem.model, problem.model.createData()
    base, end = model.getFrameId(problem.base_frame), model.getFrameId(problem.marker_frame)
    iq, iv = problem.idx_q, problem.idx_v
    w = np.array([1.0, 1.0, 1.0, rotation_weight, rotation_weight, rotation_weight])
    r = np.empty(6 * len(Q))
    J = np.empty((6 * len(Q), len(iq)))
    for i, (q_enc, M) in enumerate(zip(Q, measured)):
        q = np.array(q_enc, dtype=float)
        q[iq] += offsets
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        E = M.inverse() * data.oMf[base].inverse() * data.oMf[end]
        J_E = pin.getFrameJacobian(model, data, end, pin.ReferenceFrame.LOCAL)
        r[6 * i : 6 * i + 6] = w * pin.log6(E).vector
        J[6 * i : 6 * i + 6] = w[:, None] * (pin.Jlog6(E) @ J_E[:, iv])
    return r, J


def calibrate_joint_offsets_from_poses(
    problem: JointOffsetProblem,
    Q: np.ndarray,
    measured: Sequence[pin.SE3],
    rotation_weight: float = 0.1,
    outlier_scale: float = 0.005,
) -> PoseOffsetResult:
    """Offsets of ``problem.joints`` from encoder readings Q (N, nq) and measured poses X_BE
    (``problem.marker_frame`` in ``problem.base_frame``), all views projected at once: a robust
    (Huber, ``outlier_scale`` [m] of weighted residual) trust-region least squares, then the
    views whose residual exceeds 3 times the median and 2 ``outlier_scale`` (a wrong pose: the
    other tag-pose hypothesis, a false detection) are dropped and the rest solved again.
    Raises :class:`CalibrationError` on inconsistent input or offsets the views cannot observe."""
    from scipy.optimize import least_squares

    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    if Q.shape[1] != problem.model.nq or len(measured) != len(Q):
        raise CalibrationError(
            f"need Q (N, {problem.model.nq}) and N measured poses, got {Q.shape} and "
            f"{len(measured)}"
        )
    if not np.all(np.isfinite(Q)) or not all(np.all(np.isfinite(M.homogeneous)) for M in measured):
        raise CalibrationError("configurations and measured poses must be finite")
    k = len(problem.joints)
    if 6 * len(Q) < k:
        raise CalibrationError(f"{len(Q)} views give {6 * len(Q)} equations for {k} offsets")

    def solve(views: np.ndarray, x0: np.ndarray, loss: str) -> np.ndarray:
        Qv, Mv = Q[views], [measured[i] for i in views]
        # residuals and Jacobian come from one kinematics pass: evaluated once per x
        last: dict = {}

        def evaluate(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            if last.get("x") is None or not np.array_equal(last["x"], x):
                last["x"], last["rJ"] = (
                    x.copy(),
                    pose_residuals_and_jacobian(problem, Qv, Mv, x, rotation_weight),
                )
            return last["rJ"]

        return least_squares(
            lambda x: evaluate(x)[0],
            x0,
            jac=lambda x: evaluate(x)[1],
            loss=loss,
            f_scale=outlier_scale,
        ).x

    everything = np.arange(len(Q))
    x = solve(everything, np.zeros(k), "huber")
    per_view = np.linalg.norm(
        pose_residuals_and_jacobian(problem, Q, measured, x, rotation_weight)[0].reshape(-1, 6),
        axis=1,
    )
    inliers = everything[per_view <= max(3.0 * np.median(per_view), 2.0 * outlier_scale)]
    if len(inliers) < len(Q):
        x = solve(inliers, x, "linear")
    r, J = pose_residuals_and_jacobian(
        problem, Q[inliers], [measured[i] for i in inliers], x, rotation_weight
    )
    _, singular, Vt = np.linalg.svd(J, full_matrices=False)
    if singular[-1] < 1e-6 * singular[0]:
        mixed = [problem.joints[i] for i in np.flatnonzero(np.abs(Vt[-1]) > 0.1)]
        raise CalibrationError(
            f"offsets not observable from these views: {', '.join(mixed)} change together "
            "without changing any measured pose; vary every calibrated joint"
        )
    sigma2 = (r @ r) / max(1, len(r) - k)
    r6 = pose_residuals_and_jacobian(problem, Q, measured, x, rotation_weight)[0].reshape(-1, 6)
    return PoseOffsetResult(
        offsets=x,
        offsets_std=np.sqrt(np.diag(sigma2 * np.linalg.inv(J.T @ J))),
        position_residuals=np.linalg.norm(r6[:, :3], axis=1),
        rotation_residuals=np.linalg.norm(r6[:, 3:], axis=1) / rotation_weight,
        outliers=tuple(int(i) for i in np.setdiff1d(everything, inliers)),
    )
