"""Constraints (inequalities) and tasks (equalities) on the augmented robot.

The mink shape: every object computes a value and its Jacobian at one evaluated configuration
(:class:`~marionette.footsteps.augmented_robot.AugmentedKinematics`), Jacobian columns being
[steps (3k) | robot (nv) when the posture is free].

* :class:`Constraint`: ``compute_value(kin) -> (m,)``, feasible when every entry is ≥ 0.
* :class:`Task`: ``compute_error(kin) -> (m,)``, satisfied when 0.

Step and joint limits (eq. 2.82) are box bounds on the variables: :class:`StepLimits`,
:func:`joint_limits`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from marionette.footsteps.augmented_robot import AugmentedKinematics, rotation_2d, wrap_angle
from marionette.footsteps.errors import InvalidProblem
from marionette.footsteps.obstacles import Bar, CircleObstacle, Obstacle, RectangleObstacle
from marionette.footsteps.robot_model import FootShape

_S = np.array([[0.0, -1.0], [1.0, 0.0]])  # +90° rotation


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class Constraint:
    """Inequality g(q) ≥ 0 on the augmented robot."""

    name = "constraint"

    def compute_value(self, kin: AugmentedKinematics) -> np.ndarray:
        raise NotImplementedError

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        raise NotImplementedError


class Task:
    """Equality e(q) = 0 on the augmented robot.

    ``max_step``: the optimiser asks each Gauss–Newton iteration to remove at most this much
    of ||e|| (error clamping, as IK solvers do), so that a far target does not drag the
    linearisation of the levels above it out of its domain of validity.
    """

    name = "task"
    max_step = np.inf
    regularisation = False  # True: only shapes the solution; ignored by convergence tests
    best_effort = False  # True: scaled down instead of a proxsuite QP when limits bind and
    # the active-set paths fail (lowest level; see hierarchy)

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        raise NotImplementedError

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        raise NotImplementedError


# -- step limits (virtual joint limits, eq. 2.82) ----------------------------------------------
@dataclass(frozen=True)
class StepBounds:
    """Bounds of one step Δ = (Δx, Δy, Δθ) for a LEFT foot moving (mirrored for the right).

    Δy is the lateral offset of the moving foot from the other one, so for a left step it is
    positive; for a right step the bounds are [-max_width, -min_width] and Δθ is mirrored. A
    negative ``min_width`` lets the foot cross over (only for virtual joints, e.g. the free
    stance of full replanning; real steps keep the non-overlap constraint).
    """

    min_length: float = -0.10  # Δx [m] (backwards)
    max_length: float = 0.22  # Δx [m] (forwards)
    min_width: float = 0.16  # |Δy| [m]
    max_width: float = 0.30  # |Δy| [m]
    max_outward_yaw: float = 0.30  # Δθ towards the outside [rad]
    max_inward_yaw: float = 0.30  # Δθ towards the other foot [rad]

    def __post_init__(self) -> None:
        if not (
            self.min_length < self.max_length
            and self.min_width < self.max_width
            and self.max_outward_yaw >= 0.0
            and self.max_inward_yaw >= 0.0
        ):
            raise InvalidProblem(f"inconsistent step bounds {self}")

    def lower_upper(self, is_left: bool) -> tuple[np.ndarray, np.ndarray]:
        if is_left:
            return (
                np.array([self.min_length, self.min_width, -self.max_inward_yaw]),
                np.array([self.max_length, self.max_width, self.max_outward_yaw]),
            )
        return (
            np.array([self.min_length, -self.max_width, -self.max_outward_yaw]),
            np.array([self.max_length, -self.min_width, self.max_inward_yaw]),
        )


@dataclass
class StepLimits:
    """Per-step bounds: ``default`` everywhere, ``overrides[i]`` for step i (e.g. over a bar),
    ``final`` for the last step (the final double support: a square stance, so the final
    posture stands on both feet evenly)."""

    default: StepBounds = field(default_factory=StepBounds)
    overrides: dict[int, StepBounds] = field(default_factory=dict)
    final: StepBounds | None = None

    def bounds(
        self, is_left: np.ndarray, with_final: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Lower, upper (3k,) for steps 1..k given the side of each moving foot (k,)."""
        key = (
            is_left.tobytes(),
            with_final,
            id(self.default),
            id(self.final),
            tuple(sorted((i, id(b)) for i, b in self.overrides.items())),
        )
        cache = self.__dict__.setdefault("_cache", {})
        if key not in cache:
            cache[key] = self._bounds(is_left, with_final)
        return cache[key]

    def _bounds(self, is_left: np.ndarray, with_final: bool) -> tuple[np.ndarray, np.ndarray]:
        k = is_left.shape[0]
        lo, hi = np.empty((k, 3)), np.empty((k, 3))
        for i in range(k):
            b = self.overrides.get(i + 1, self.default)
            if with_final and i == k - 1 and self.final is not None:
                b = self.final
            lo[i], hi[i] = b.lower_upper(bool(is_left[i]))
        lower, upper = lo.reshape(-1), hi.reshape(-1)
        lower.flags.writeable = upper.flags.writeable = False
        return lower, upper


FINAL_STANCE = StepBounds(
    min_length=-0.05,
    max_length=0.05,
    min_width=0.16,
    max_width=0.24,
    max_outward_yaw=0.1,
    max_inward_yaw=0.1,
)


def joint_limits(
    model: pin.Model, q: np.ndarray, posture_limits: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity-space bounds (nv,) keeping q ⊕ v within the joint limits (free-flyer unbounded).

    ``posture_limits`` (lower, upper), each (nq,), tighten the model's limits (e.g. a comfort
    band around the reference posture). Valid for the robots here: every joint after the
    free-flyer is 1-dof revolute/prismatic, so q index = v index + 1.
    """
    lower = model.lowerPositionLimit[7:]
    upper = model.upperPositionLimit[7:]
    if posture_limits is not None:
        lower = np.maximum(lower, posture_limits[0][7:])
        upper = np.minimum(upper, posture_limits[1][7:])
    lo = np.full(model.nv, -np.inf)
    hi = np.full(model.nv, np.inf)
    lo[6:] = lower - q[7:]
    hi[6:] = upper - q[7:]
    return lo, hi


# -- inequality constraints ----------------------------------------------------------------------
class FootNonOverlap(Constraint):
    """Successive footprints never overlap (Dang's self-collision of the virtual chain).

    Sufficient condition, smooth in the step variables: the 4 corners of foot i lie beyond the
    outer edge of foot i-1 (plus ``margin``) along the lateral axis of foot i-1, on the side of
    foot i. Then foot i's rectangle (the hull of its corners) is disjoint from foot i-1's.
    In the frame of foot i-1 a corner c (sole frame) of foot i is at (Δx, Δy) + R(Δθ) c, so
    the rows of step i depend on Δ_i alone:
        s_i (Δy_i + sin Δθ_i c_x + cos Δθ_i c_y) − width/2 − margin ≥ 0,   s_i = ±1 (left/right).
    Rows: 4 per step i ∈ [first_step, k].
    """

    name = "foot_non_overlap"

    def __init__(self, margin: float = 0.02, first_step: int = 1) -> None:
        if margin < 0.0:
            raise InvalidProblem(f"margin must be >= 0, got {margin}")
        self.margin = margin
        self.first_step = max(1, first_step)

    def _parts(self, kin):
        steps = np.arange(self.first_step, kin.k + 1)
        delta = kin.config.steps[steps - 1]  # (m, 3)
        sign = np.where(kin.is_left[steps + 1], 1.0, -1.0)  # side of the moving foot
        c = kin.augmented.foot_corners  # (4, 2)
        sin, cos = np.sin(delta[:, 2])[:, None], np.cos(delta[:, 2])[:, None]
        return steps, delta, sign, c, sin, cos

    def compute_value(self, kin: AugmentedKinematics) -> np.ndarray:
        _, delta, sign, c, sin, cos = self._parts(kin)
        lateral = delta[:, 1:2] + sin * c[None, :, 0] + cos * c[None, :, 1]  # (m, 4)
        half_width = 0.5 * kin.augmented.foot.width
        return (sign[:, None] * lateral - half_width - self.margin).reshape(-1)

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        steps, _, sign, c, sin, cos = self._parts(kin)
        m = steps.shape[0]
        J = np.zeros((4 * m, kin.nv))
        rows = np.arange(4 * m)
        col = np.repeat(3 * (steps - 1), 4)
        J[rows, col + 1] = np.repeat(sign, 4)
        J[rows, col + 2] = (sign[:, None] * (cos * c[None, :, 0] - sin * c[None, :, 1])).reshape(-1)
        return J


class ObstacleAvoidance(Constraint):
    """Every footprint i ∈ [first_step, k] stays ``buffer`` away from every obstacle region.

    Circles: exact signed distance from the disc centre to the sole rectangle, minus radius and
    buffer (1 row). Rectangles and bars: separating-axis gap along the best of the 4 candidate
    axes at the current configuration (a lower bound of the distance, so ≥ buffer implies
    clearance), written per corner to stay smooth (4 rows). Footprint/obstacle pairs farther
    apart than ``influence`` [m] are skipped (they cannot touch within one iteration).
    """

    name = "obstacles"

    def __init__(
        self, obstacles: list[Obstacle], first_step: int = 1, influence: float = 1.0
    ) -> None:
        self.obstacles = [o.floor_region() if isinstance(o, Bar) else o for o in obstacles]
        for o in self.obstacles:
            if not isinstance(o, (CircleObstacle, RectangleObstacle)):
                raise InvalidProblem(f"unsupported obstacle {o!r}")
        self.first_step = max(1, first_step)
        self.influence = influence

    def _pairs(self, kin):
        steps = np.arange(self.first_step, kin.k + 1)
        reach = 0.5 * np.hypot(kin.augmented.foot.length, kin.augmented.foot.width)
        pairs = []
        for i in steps:
            p = kin.footprints[i + 1, :2]
            for o in self.obstacles:
                extent = (
                    o.radius if isinstance(o, CircleObstacle) else 0.5 * np.hypot(o.length, o.width)
                )
                if np.linalg.norm(p - o.center) < reach + extent + o.buffer + self.influence:
                    pairs.append((int(i), o))
        return pairs

    def compute_value(self, kin: AugmentedKinematics) -> np.ndarray:
        foot = kin.augmented.foot
        rows = [sole_clearance(kin.footprints[i + 1], foot, o)[0] for i, o in self._pairs(kin)]
        return np.concatenate(rows) if rows else np.zeros(0)

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        foot = kin.augmented.foot
        rows = [
            sole_clearance(kin.footprints[i + 1], foot, o)[1] @ kin.footprint_jacobian(i)
            for i, o in self._pairs(kin)
        ]
        return np.vstack(rows) if rows else np.zeros((0, kin.nv))


def sole_clearance(pose: np.ndarray, foot: FootShape, obstacle) -> tuple[np.ndarray, np.ndarray]:
    """Clearance rows of a sole at ``pose`` (x, y, yaw) from ``obstacle`` minus its buffer.

    Returns (values (m,), d values / d pose (m, 3)); the sole is clear when every value ≥ 0.
    Circle: signed distance from the disc centre to the sole rectangle − radius (1 row).
    Rectangle: separating-axis gap on the best of the 4 candidate axes at this pose, one row
    per corner so that it stays smooth (4 rows); a gap ≥ buffer implies a distance ≥ buffer.
    """
    o = obstacle.floor_region() if isinstance(obstacle, Bar) else obstacle
    half = np.array([0.5 * foot.length, 0.5 * foot.width])
    R = rotation_2d(pose[2])
    if isinstance(o, CircleObstacle):
        c_F = R.T @ (o.center - pose[:2])
        outside = np.abs(c_F) > half
        if np.any(outside):
            q = np.clip(c_F, -half, half)
            dist = np.linalg.norm(c_F - q)
            grad = (c_F - q) / dist
        else:  # centre inside the sole: negative penetration depth along the nearer edge
            slack = half - np.abs(c_F)
            axis = int(np.argmin(slack))
            dist = -slack[axis]
            grad = np.zeros(2)
            grad[axis] = 1.0 if c_F[axis] >= 0.0 else -1.0  # d|c|/dc
        value = np.array([dist - o.radius - o.buffer])
        # dc_F = −Rᵀ dp + (c_F.y, −c_F.x) dθ
        d_pose = np.concatenate([grad @ (-R.T), [grad @ np.array([c_F[1], -c_F[0]])]])
        return value, d_pose[None, :]
    if not isinstance(o, RectangleObstacle):
        raise InvalidProblem(f"unsupported obstacle {obstacle!r}")
    axes_o = o.axes()
    half_o = np.array([0.5 * o.length, 0.5 * o.width])
    axes_f = R.T  # rows: the sole's x and y axes in world
    corners_local = foot.corners()
    corners_f = pose[:2] + corners_local @ R.T
    corners_o = o.corners()
    best: tuple[str, int, float] | None = None
    best_gap = -np.inf
    for owner, axes in (("o", axes_o), ("f", axes_f)):
        for a in range(2):
            for sgn in (1.0, -1.0):
                n = sgn * axes[a]
                gap = np.min(corners_f @ n) - np.max(corners_o @ n)
                if gap > best_gap:
                    best, best_gap = (owner, a, sgn), gap
    if best is None:  # every gap NaN
        raise InvalidProblem(f"foot pose {pose} or obstacle {obstacle!r} is not finite")
    owner, a, sgn = best
    if owner == "o":
        n = sgn * axes_o[a]
        value = corners_f @ n - n @ o.center - half_o[a] - o.buffer
        # corner c = p + R c_loc: dc = dp + S R c_loc dθ
        d_theta = (corners_local @ R.T) @ (_S.T @ n)
        return value, np.column_stack([np.tile(n, (4, 1)), d_theta])
    # Axis of the sole: n = sgn·axis_f[a](θ); one row per obstacle corner.
    n = sgn * axes_f[a]
    dn = sgn * (axes_f[1] if a == 0 else -axes_f[0])  # dn/dθ
    value = (pose[:2] - corners_o) @ n - half[a] - o.buffer
    return value, np.column_stack([np.tile(n, (4, 1)), (pose[:2] - corners_o) @ dn])


class ComInSupportPolygon(Constraint):
    """The CoM's floor projection lies ``margin`` inside the hull of the last two soles.

    Dang §6.1.1: "the CoM has to stay inside the support polygon at the end of the movement".
    One row per edge of the convex hull of the 8 sole corners (hull computed at the current
    configuration, edges kept counter-clockwise): n_e·(c − a_e) − margin ≥ 0, n_e the inward
    unit normal of edge a_e → b_e.
    """

    name = "com_support"

    def __init__(self, margin: float = 0.03) -> None:
        self.margin = margin

    def _hull(self, kin):
        idx = np.array([kin.k - 1, kin.k])
        corners = kin.corners(idx).reshape(-1, 2)  # (8, 2)
        owner = np.repeat(idx, 4)
        hull = _convex_hull_ccw(corners)
        return corners, owner, hull

    def compute_value(self, kin: AugmentedKinematics) -> np.ndarray:
        corners, _, hull = self._hull(kin)
        c = kin.com()[:2]
        a, b = corners[hull], corners[np.roll(hull, -1)]
        u = b - a
        n = (u @ _S.T) / np.linalg.norm(u, axis=1)[:, None]
        return np.einsum("ej,ej->e", n, c - a) - self.margin

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        corners, owner, hull = self._hull(kin)
        c = kin.com()[:2]
        J_c = kin.com_jacobian()[:2]  # (2, nv)
        J_corners = kin.points_jacobian(corners, owner)  # (8, 2, nv)
        nxt = np.roll(hull, -1)
        a, b = corners[hull], corners[nxt]
        Ja, Jb = J_corners[hull], J_corners[nxt]
        u = b - a
        L = np.linalg.norm(u, axis=1)
        uh = u / L[:, None]
        n = uh @ _S.T
        # value = n·(c − a);  dn = S (I − ûûᵀ) du / |u|
        P = np.eye(2)[None] - uh[:, :, None] * uh[:, None, :]
        w = np.einsum("ej,jk,ekl->el", c - a, _S, P) / L[:, None]  # (c − a)ᵀ S P / |u|
        J = np.einsum("ej,ejv->ev", n, J_c[None] - Ja) + np.einsum("ej,ejv->ev", w, Jb - Ja)
        return J


def _convex_hull_ccw(points: np.ndarray) -> np.ndarray:
    """Indices of the convex hull of (n, 2) points, counter-clockwise (Andrew's monotone chain)."""
    order = np.lexsort((points[:, 1], points[:, 0]))

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[int] = []
    upper: list[int] = []
    for i in order:
        while len(lower) >= 2 and cross(points[lower[-2]], points[lower[-1]], points[i]) <= 1e-12:
            lower.pop()
        lower.append(i)
    for i in order[::-1]:
        while len(upper) >= 2 and cross(points[upper[-2]], points[upper[-1]], points[i]) <= 1e-12:
            upper.pop()
        upper.append(i)
    return np.array(lower[:-1] + upper[:-1])


# -- tasks -----------------------------------------------------------------------------------
class FeetOnFootprints(Task):
    """Closure of the augmented robot: the robot's soles lie on P_k and P_(k-1) (12 rows).

    Per sole: position error p_sole − p_footprint (3) and orientation error
    log3(R_footprintᵀ R_sole) (3), whose Jacobian is Jlog3 · R_soleᵀ (ω_sole − ω_footprint).
    """

    name = "feet_on_footprints"

    def _pairs(self, kin):
        robot = kin.augmented.robot
        out = []
        for i in (kin.k, kin.k - 1):
            side = "left" if kin.is_left[i + 1] else "right"
            out.append((i, robot.sole_frames[side]))
        return out

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        err = []
        z = kin.augmented.stance.floor_z
        for i, frame in self._pairs(kin):
            p, R = kin.frame_placement(frame)
            fp = kin.footprint(i)
            err.append(p - np.array([fp[0], fp[1], z]))
            err.append(pin.log3(_rz(fp[2]).T @ R))
        return np.concatenate(err)

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        rows = []
        for i, frame in self._pairs(kin):
            _, R = kin.frame_placement(frame)
            fp = kin.footprint(i)
            J_frame = kin.frame_jacobian(frame)
            J_fp = kin.footprint_jacobian(i)
            J_lin = J_frame[:3].copy()
            J_lin[:2] -= J_fp[:2]
            w = J_frame[3:].copy()
            w[2] -= J_fp[2]
            R_rel = _rz(fp[2]).T @ R
            rows.append(J_lin)
            rows.append(pin.Jlog3(R_rel) @ R.T @ w)
        return np.vstack(rows)


def _finite_vector(value: ArrayLike, size: int, what: str) -> np.ndarray:
    """``value`` as a (size,) array; raises InvalidProblem "<what>, got <value>" unless it is
    ``size`` finite numbers."""
    v = np.asarray(value, dtype=float).reshape(-1)
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise InvalidProblem(f"{what}, got {value!r}")
    return v


def _rz(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class FramePositionTask(Task):
    """A robot point reaches ``target`` (world, 3) — the hand task of Dang §6.1.1.

    ``axes``: the world axes constrained (default x, y, z). With the posture frozen the hand's
    height cannot change (flat floor), so the planner uses (0, 1) there.
    """

    name = "hand"
    max_step = 0.1

    def __init__(
        self,
        frame: str,
        target: np.ndarray,
        name: str | None = None,
        axes: tuple[int, ...] = (0, 1, 2),
    ) -> None:
        self.frame = frame
        self.set_target(target)
        self.axes = np.asarray(axes, dtype=int)
        if name:
            self.name = name

    def set_target(self, target: ArrayLike) -> None:
        self.target = _finite_vector(target, 3, "target must be 3 finite numbers")

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        return (kin.frame_placement(self.frame)[0] - self.target)[self.axes]

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        return kin.frame_jacobian(self.frame)[self.axes]


class GazeTask(Task):
    """The camera's optical axis (z) points at ``target`` (world, 3): 2 rows.

    Error: the (x, y) components of u = p_C / |p_C|, p_C = Rᵀ (target − p_camera) the target in
    the camera frame (sines of the angles off the optical axis; zero when centred in the image).
    dp_C = Rᵀ ([t − p]× J_ang − J_lin) dv,  du = (I − u uᵀ) dp_C / |p_C|.
    """

    name = "gaze"
    max_step = 0.2

    def __init__(self, camera_frame: str, target: np.ndarray) -> None:
        self.frame = camera_frame
        self.set_target(target)

    def set_target(self, target: ArrayLike) -> None:
        self.target = _finite_vector(target, 3, "target must be 3 finite numbers")

    def _p_C(self, kin: AugmentedKinematics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p, R = kin.frame_placement(self.frame)
        return p, R, R.T @ (self.target - p)

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        _, _, p_C = self._p_C(kin)
        return p_C[:2] / np.linalg.norm(p_C)

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        p, R, p_C = self._p_C(kin)
        J = kin.frame_jacobian(self.frame)
        dp_C = R.T @ (_skew(self.target - p) @ J[3:] - J[:3])
        norm = np.linalg.norm(p_C)
        u = p_C / norm
        du = (np.eye(3) - np.outer(u, u)) @ dp_C / norm
        return du[:2]


class PostureTask(Task):
    """Joints (not the free-flyer, not the frozen ones) stay near ``reference`` (Dang §6.1.1)."""

    name = "posture"
    max_step = 0.3

    def __init__(self, reference: np.ndarray, velocity_indices: np.ndarray) -> None:
        self.reference = np.asarray(reference, dtype=float)
        self.indices = np.asarray(velocity_indices, dtype=int)

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        # Revolute joints after the free-flyer: q index = v index + 1.
        q = kin.config.require_q_robot()
        return q[self.indices + 1] - self.reference[self.indices + 1]

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        J = np.zeros((self.indices.shape[0], kin.nv))
        if kin.robot_free:
            J[np.arange(self.indices.shape[0]), kin.nv_steps + self.indices] = 1.0
        return J


class StepPreferenceTask(Task):
    """Lowest priority: short, even, straight steps, feet parallel at the nominal width.

    Dang §3.2.1's "preferred configuration" term. Rows per free step i ∈ [first, last]:
    length_weight·Δx_i, Δy_i − s_i·width (s_i = +1 for a left step), yaw_weight·Δθ_i. In the
    room left by the tasks above, Σ Δx_i² small spreads the walked distance evenly over the
    steps, and Δθ_i → 0 stops the chain from turning: without it the least-norm motion of the
    chain favours yaws (a yaw near the root moves the far end by its lever arm) and the plan
    curls up.
    """

    name = "step_preference"
    best_effort = False

    def __init__(
        self,
        width: float,
        first_step: int = 1,
        last_step: int | None = None,
        length_weight: float = 0.5,
        yaw_weight: float = 1.0,
    ) -> None:
        if width <= 0.0:
            raise InvalidProblem(f"nominal width must be > 0, got {width}")
        self.width = width
        self.first_step = max(1, first_step)
        self.last_step = last_step
        self.weights = np.array([length_weight, 1.0, yaw_weight])

    def _steps(self, kin):
        if self.last_step is None:
            last = kin.k
        elif self.last_step < 0:  # counted from the end: -1 = all but the last
            last = kin.k + self.last_step
        else:
            last = min(self.last_step, kin.k)
        return np.arange(self.first_step, last + 1)

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        steps = self._steps(kin)
        e = kin.config.steps[steps - 1].copy()
        e[:, 1] -= np.where(kin.is_left[steps + 1], 1.0, -1.0) * self.width
        return (e * self.weights).reshape(-1)

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        steps = self._steps(kin)
        m = steps.shape[0]
        J = np.zeros((3 * m, kin.nv))
        cols = (3 * (steps - 1))[:, None] + np.arange(3)[None, :]
        J[np.arange(3 * m), cols.reshape(-1)] = np.tile(self.weights, m)
        return J


class FootprintPoseTask(Task):
    """Footprint ``index`` (0..k; None: the last one) reaches ``target`` (x, y, yaw) in world.

    Dang §3.3's "position task for designated step"; also holds the crossing steps on a bar
    (Algorithm 3). ``weights`` (3,) scale the rows (e.g. 0 on yaw to leave it free).
    """

    name = "footprint"
    max_step = 0.3

    def __init__(self, index: int | None, target, weights=(1.0, 1.0, 0.5), name: str | None = None):
        self.index = index
        self.set_target(target)
        self.weights = np.asarray(weights, dtype=float)
        if name:
            self.name = name

    def set_target(self, target: ArrayLike) -> None:
        self.target = _finite_vector(target, 3, "footprint target must be (x, y, yaw)")

    def _index(self, kin) -> int:
        i = kin.k if self.index is None else self.index
        if not 0 <= i <= kin.k:
            raise InvalidProblem(f"footprint task on step {self.index} but the plan has {kin.k}")
        return i

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        fp = kin.footprint(self._index(kin))
        e = np.array(
            [fp[0] - self.target[0], fp[1] - self.target[1], wrap_angle(fp[2] - self.target[2])]
        )
        return self.weights * e

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        return self.weights[:, None] * kin.footprint_jacobian(self._index(kin))


class StanceGoalTask(Task):
    """The final stance reaches ``target`` (x, y, yaw): midpoint of the last two soles and
    yaw of the last one (side-agnostic goal for footsteps-only planning, Dang §3.3)."""

    name = "stance_goal"
    max_step = 0.3

    def __init__(self, target, yaw_weight: float = 0.5) -> None:
        self.set_target(target)
        self.yaw_weight = yaw_weight

    def set_target(self, target: ArrayLike) -> None:
        self.target = _finite_vector(target, 3, "footprint target must be (x, y, yaw)")

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        mid = 0.5 * (kin.footprint(kin.k)[:2] + kin.footprint(kin.k - 1)[:2])
        yaw = wrap_angle(kin.footprint(kin.k)[2] - self.target[2])
        return np.array([mid[0] - self.target[0], mid[1] - self.target[1], self.yaw_weight * yaw])

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        J_last = kin.footprint_jacobian(kin.k)
        J_prev = kin.footprint_jacobian(kin.k - 1)
        J = np.empty((3, kin.nv))
        J[:2] = 0.5 * (J_last[:2] + J_prev[:2])
        J[2] = self.yaw_weight * J_last[2]
        return J


class FacingTask(Task):
    """The last footprint faces the approach direction: its yaw equals the bearing of ``target``
    (x, y[, z]) from ``origin`` (x, y), the initial stance centre (1 row).

    Without it the posture task, which does not see the robot's heading, lets the whole robot
    turn away (up to 50° in tests) to bring a hand closer to its reference pose; with it the
    robot arrives facing the way it walked, the object in front.

    e = wrap(θ_k − atan2(t_y − o_y, t_x − o_x)),  J = ∂θ_k/∂q.
    """

    name = "facing"
    max_step = 0.2

    def __init__(self, target, origin) -> None:
        o = np.asarray(origin, dtype=float).reshape(-1)
        if o.shape[0] < 2 or not np.all(np.isfinite(o)):
            raise InvalidProblem(f"facing origin must be finite (x, y), got {origin!r}")
        self.origin = o[:2]
        self.set_target(target)

    def set_target(self, target) -> None:
        t = np.asarray(target, dtype=float).reshape(-1)
        if t.shape[0] < 2 or not np.all(np.isfinite(t)):
            raise InvalidProblem(f"facing target must be finite (x, y[, z]), got {target!r}")
        self.target = t[:2]
        d = self.target - self.origin
        self.heading = float(np.arctan2(d[1], d[0]))

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        return np.array([wrap_angle(kin.footprint(kin.k)[2] - self.heading)])

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        return kin.footprint_jacobian(kin.k)[2:3]


class ReachTask(Task):
    """The object sits at ``offset`` (forward, left) [m] in the final stance frame (2 rows):
    the stance centre m = (p_k + p_(k-1)) / 2 with the yaw θ_k of the last footprint.

    The reference posture alone would choose where to stand from the reference arm pose (a
    humanoid's half-sitting posture may hold the grippers 0.43 m to the sides, so the robot stood
    half a metre beside
    the object and reached across); this places the stance the way one approaches to grasp.
    e = R(θ_k)ᵀ (t − m) − offset,  de = −R(θ_k)ᵀ dm + S' R(θ_k)ᵀ (t − m) dθ_k, S' = [[0,1],[-1,0]].
    """

    name = "reach"
    max_step = 0.2

    def __init__(self, target, offset) -> None:
        self.offset = np.asarray(offset, dtype=float).reshape(2)
        self.set_target(target)

    def set_target(self, target) -> None:
        t = np.asarray(target, dtype=float).reshape(-1)
        if t.shape[0] < 2 or not np.all(np.isfinite(t)):
            raise InvalidProblem(f"reach target must be finite (x, y[, z]), got {target!r}")
        self.target = t[:2]

    def _parts(self, kin):
        mid = 0.5 * (kin.footprint(kin.k)[:2] + kin.footprint(kin.k - 1)[:2])
        Rt = rotation_2d(kin.footprint(kin.k)[2]).T
        return mid, Rt, Rt @ (self.target - mid)

    def compute_error(self, kin: AugmentedKinematics) -> np.ndarray:
        return self._parts(kin)[2] - self.offset

    def compute_jacobian(self, kin: AugmentedKinematics) -> np.ndarray:
        _, Rt, local = self._parts(kin)
        J_last = kin.footprint_jacobian(kin.k)
        J_mid = 0.5 * (J_last[:2] + kin.footprint_jacobian(kin.k - 1)[:2])
        return -Rt @ J_mid + np.outer([local[1], -local[0]], J_last[2])
