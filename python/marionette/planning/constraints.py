"""Numerical constraints f(q) = rhs with analytic Jacobians (thesis §2.2.1, §3.2.1).

A constraint is a residual and its Jacobian, the contract of a C++ ``Feature``:
``compute_error(kin) -> (size,)`` is ``f(q) - rhs`` and ``compute_jacobian(kin) -> (size, nv)``
its derivative with respect to the velocity ``v`` (Pinocchio's tangent space), both read from a
:class:`Kinematics` workspace updated once per configuration.  A *parametrised* constraint
(thesis §3.2.1: g(q) = g0) takes its right-hand side from a configuration with
``rhs_from(kin)``; the others have a fixed rhs (0, or a margin).

Explicit constraints (HPP's explicit form, "by substitution") give output joint values as a
function of the other variables: :class:`ExplicitRelativePose` (a grasped object's pose is the
gripper pose times a constant) and :class:`LockedJoint` (a joint fixed to a value).  The
projector substitutes them instead of iterating, and each has ``as_implicit()`` for when two of
them would determine the same joint.

Frames follow Drake's monogram notation: ``X_AB`` is the pose of B in A, ``M_JF`` the constant
pose of frame F in the frame of joint J.  Rotation errors use log3 (R3 x SO3, as HPP's
``RelativeTransformationR3xSO3``); rows are selected by a 6-entry mask.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from marionette.planning.problem import ContactSurface, ManipulationProblem


class ConstraintError(ValueError):
    """A constraint that cannot be built (bad mask, unknown joint, mismatched sizes)."""


class Kinematics:
    """Workspace of one thread: Pinocchio data at the last configuration given to :meth:`update`.

    After ``update(q)``: ``data.oMi`` (joint poses), joint Jacobians (LOCAL) and the centre of
    mass are those of q.  Constraints only read from it.
    """

    def __init__(self, model: pin.Model) -> None:
        self.model = model
        self.data = model.createData()
        self.oMi = self.data.oMi
        self.q = pin.neutral(model)
        self._com_valid = False
        self.version = 0  # bumped by every update: constraints cache per-version values
        self._jac: dict[int, np.ndarray] = {}
        # Joints whose motion is irrelevant to the caller (locked): their Jacobian reads as 0.
        self.static: frozenset[int] = frozenset()
        self._zero = np.zeros((6, model.nv))
        # A free-flyer hanging from the universe has the constant LOCAL Jacobian [0 I6 0]
        # (its velocity is its body twist): valid even after its pose is patched in oMi.
        self._root_ff: dict[int, np.ndarray] = {}
        for j in range(1, model.njoints):
            if model.joints[j].nq == 7 and model.parents[j] == 0:
                J = np.zeros((6, model.nv))
                J[:, model.idx_vs[j] : model.idx_vs[j] + 6] = np.eye(6)
                self._root_ff[j] = J

    def update(self, q: np.ndarray, jacobians: bool = True) -> None:
        """Forward kinematics at q (nq); with ``jacobians``, also all joint Jacobians."""
        self.q = q
        if jacobians:
            pin.computeJointJacobians(self.model, self.data, q)
        else:
            pin.forwardKinematics(self.model, self.data, q)
        self._com_valid = False
        self.version += 1
        self._jac.clear()

    def joint_placement(self, joint_id: int) -> pin.SE3:
        return self.oMi[joint_id]

    def joint_jacobian(self, joint_id: int) -> np.ndarray:
        """(6 x nv) body Jacobian of joint ``joint_id`` in its own frame (Pinocchio LOCAL)."""
        J = self._jac.get(joint_id)
        if J is None:
            if joint_id in self.static:
                J = self._zero
            elif joint_id in self._root_ff:
                J = self._root_ff[joint_id]
            else:
                J = pin.getJointJacobian(self.model, self.data, joint_id, pin.LOCAL)
            self._jac[joint_id] = J
        return J

    def set_joint_placement(self, joint_id: int, X: pin.SE3) -> None:
        """Patch the pose of a leaf joint (an object moved by substitution) without new FK."""
        self.oMi[joint_id] = X
        self.version += 1

    def com(self) -> np.ndarray:
        if not self._com_valid:
            pin.jacobianCenterOfMass(self.model, self.data, self.q, False)
            self._com_valid = True
        return self.data.com[0]

    def com_jacobian(self) -> np.ndarray:
        """(3 x nv) Jacobian of the centre of mass in the world frame."""
        self.com()
        return self.data.Jcom


def _pose_list(M: pin.SE3) -> list[float]:
    """[x, y, z, qx, qy, qz, qw] of a pose (for files)."""
    return [float(v) for v in pin.SE3ToXYZQUAT(M)]


# Which rows a constraint keeps: booleans, as a sequence or a bool array.
Mask = Sequence[bool] | np.ndarray


def _check_mask(mask: Mask) -> np.ndarray:
    m = np.asarray(mask, dtype=bool)
    if m.shape != (6,):
        raise ConstraintError(f"a mask has 6 entries (x y z rx ry rz), got {list(mask)}")
    if not m.any():
        raise ConstraintError("a mask selects at least one row")
    return m


class Constraint:
    """Implicit numerical constraint f(q) = rhs; see the module docstring for the contract."""

    name: str
    size: int
    parametrised: bool = False

    def __init__(self, name: str, size: int, parametrised: bool = False) -> None:
        self.name = name
        self.size = size
        self.parametrised = parametrised
        self.rhs = np.zeros(size)

    def value(self, kin: Kinematics) -> np.ndarray:
        """f(q) (size,)."""
        raise NotImplementedError

    def compute_error(self, kin: Kinematics) -> np.ndarray:
        """f(q) - rhs (size,)."""
        return self.value(kin) - self.rhs

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        """df/dv (size x nv)."""
        raise NotImplementedError

    def rhs_from(self, kin: Kinematics) -> np.ndarray:
        """The right-hand side that q satisfies (thesis: g0 = g(q_start))."""
        return self.value(kin).copy()

    def joints(self) -> set[int]:
        """Joints whose motion changes f (for the relative-motion analysis of path validation)."""
        return set()

    def to_dict(self, model: pin.Model) -> dict:
        """Definition for files (a controller builds its task from it)."""
        return {
            "type": type(self).__name__,
            "size": self.size,
            "parametrised": self.parametrised,
            "rhs": self.rhs.tolist(),
        }

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, size={self.size})"


class RelativeTransformation(Constraint):
    """Pose of frame F2 (on joint2) in frame F1 (on joint1): e = [p, log3(R)] - rhs on mask rows.

    With X_1 = oMi[joint1] M1 and X_2 = oMi[joint2] M2, M = X_1^-1 X_2 = (R, p).  The body twist
    of M in F2 is nu = J_2 - Ad(M^-1) J_1 (J_i: LOCAL Jacobians of F_i), so
    dp = R nu_lin and d log3(R) = Jlog3(R) nu_ang.  joint1 = 0 gives an absolute transformation.
    """

    def __init__(
        self,
        name: str,
        joint1: int,
        M1: pin.SE3,
        joint2: int,
        M2: pin.SE3,
        mask: Mask = (True,) * 6,
        rhs: np.ndarray | None = None,
        parametrised: bool = False,
    ) -> None:
        self.mask = _check_mask(mask)
        super().__init__(name, int(self.mask.sum()), parametrised)
        if joint1 == joint2:
            raise ConstraintError(f"{name}: both frames are on joint {joint1}; f would be constant")
        self.joint1, self.M1, self.joint2, self.M2 = joint1, M1, joint2, M2
        self._Ad1 = M1.inverse().action  # LOCAL Jacobian of F1 = Ad(M1^-1) J_joint1
        self._Ad2 = M2.inverse().action
        self._cache_version = -1
        self._cache_kin: Kinematics | None = None
        self._M: pin.SE3 | None = None
        self._v6: np.ndarray | None = None
        self._all = bool(self.mask.all())
        if rhs is not None:
            self.rhs = np.asarray(rhs, dtype=float).copy()
            if self.rhs.shape != (self.size,):
                raise ConstraintError(f"{name}: rhs must have {self.size} entries")

    def joints(self) -> set[int]:
        return {self.joint1, self.joint2}

    def to_dict(self, model: pin.Model) -> dict:
        """Frame F1 = (joint1, M1), frame F2 = (joint2, M2): f = [p, log3 R] of F1^-1 F2."""
        out = super().to_dict(model)
        out.update(
            {
                "joint1": model.names[self.joint1],
                "M1": _pose_list(self.M1),
                "joint2": model.names[self.joint2],
                "M2": _pose_list(self.M2),
                "mask": [bool(v) for v in self.mask],
            }
        )
        return out

    def relative_pose(self, kin: Kinematics) -> pin.SE3:
        if kin.version != self._cache_version or kin is not self._cache_kin:
            oMi = kin.oMi
            self._oMi1 = oMi[self.joint1]
            self._X2 = oMi[self.joint2] * self.M2
            self._M = (self._oMi1 * self.M1).actInv(self._X2)
            self._v6 = None
            self._cache_version, self._cache_kin = kin.version, kin
        return self._M

    def value6(self, kin: Kinematics) -> np.ndarray:
        """[p, log3(R)] of the relative pose, all 6 rows (read-only: cached per kinematics
        version, a Newton iteration reads it for the error and again for the Jacobian)."""
        M = self.relative_pose(kin)
        if self._v6 is None:
            v = np.empty(6)
            v[:3] = M.translation
            v[3:] = pin.log3(M.rotation)
            v.flags.writeable = False
            self._v6 = v
        return self._v6

    def value(self, kin: Kinematics) -> np.ndarray:
        v = self.value6(kin)
        return v if self._all else v[self.mask]

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        M = self.relative_pose(kin)
        static = kin.static
        if self.joint2 in static:
            nu = None
        else:
            nu = self._Ad2 @ kin.joint_jacobian(self.joint2)
        if self.joint1 != 0 and self.joint1 not in static:
            # Ad(M^-1) Ad(M1^-1) = Ad((M1 M)^-1) = Ad(X2^-1 oMi1): one 6x6 product.
            t = self._X2.actInv(self._oMi1).action @ kin.joint_jacobian(self.joint1)
            nu = -t if nu is None else nu - t
        if nu is None:
            return np.zeros((self.size, kin.model.nv))
        J = np.empty((6, nu.shape[1]))
        R = M.rotation
        np.matmul(R, nu[:3], out=J[:3])
        np.matmul(pin.Jlog3(R), nu[3:], out=J[3:])
        return J if self._all else J[self.mask]


def Transformation(
    name: str, joint: int, M_JF: pin.SE3, X_WT: pin.SE3, mask: Mask = (True,) * 6
) -> RelativeTransformation:
    """Absolute pose of frame F (on ``joint``) equal to the target ``X_WT`` on the mask rows."""
    return RelativeTransformation(name, 0, X_WT, joint, M_JF, mask)


def _flip(M_JS: pin.SE3) -> pin.SE3:
    """Object surface frame with z pointing into the object (rotation of pi about x)."""
    return M_JS * pin.SE3(np.diag([1.0, -1.0, -1.0]), np.zeros(3))


class Placement(Constraint):
    """An object surface lies on an environment surface (thesis §2.4.2, CP; HPP contact surfaces).

    For the active pair (object surface O, environment surface E) let F be O flipped (z into
    the object) and M = X_E^-1 X_F = (R, p).  Placement: [p_z, log3(R)_x, log3(R)_y] = [margin,
    0, 0]: the object rests ``margin`` above the plane with normals opposed.  The pair is the
    one closest to being satisfied, chosen by :meth:`select_pair` (once per projection, so the
    error is smooth while iterating).  The centre of O must also lie inside E's polygon: two
    more rows (HPP ``ConvexShapeContact``) hold c - proj_E(c), the offset of the centre c = p_xy
    from its projection on the polygon, zero inside; outside, its derivative is n n^T (nearest
    point on an edge of outward normal n) or I (nearest point a vertex) times dc/dv.
    """

    ROWS = np.array([False, False, True, True, True, False])

    def __init__(
        self,
        name: str,
        problem: ManipulationProblem,
        obj: str,
        object_contacts: Sequence[str],
        env_contacts: Sequence[str],
        margin: float = 0.0,
    ) -> None:
        super().__init__(name, 3)
        if not object_contacts or not env_contacts:
            raise ConstraintError(f"{name}: needs object and environment contact surfaces")
        self.object = obj
        self.pairs: list[tuple[ContactSurface, ContactSurface]] = [
            (problem.contacts[o], problem.contacts[e])
            for o in object_contacts
            for e in env_contacts
        ]
        self.margin = margin
        self.size = 5
        self.rhs = np.array([margin, 0.0, 0.0, 0.0, 0.0])
        self.pair = 0
        self._rel = [
            RelativeTransformation(f"{name}[{i}]", e.joint_id, e.M_JS, o.joint_id, _flip(o.M_JS))
            for i, (o, e) in enumerate(self.pairs)
        ]
        self._polygons = [_Polygon(e.polygon_S) for _, e in self.pairs]
        self._offset_key: tuple[int, int, int] | None = None
        self._offset_val: tuple[np.ndarray, np.ndarray | None] = (np.zeros(2), None)

    def joints(self) -> set[int]:
        return set().union(*(r.joints() for r in self._rel))

    def to_dict(self, model: pin.Model) -> dict:
        out = super().to_dict(model)
        out.update(
            {
                "object": self.object,
                "margin": self.margin,
                "pairs": [[o.name, e.name] for o, e in self.pairs],
                "pair": self.pair,
            }
        )
        return out

    def relative_pose(self, kin: Kinematics, pair: int | None = None) -> pin.SE3:
        return self._rel[self.pair if pair is None else pair].relative_pose(kin)

    def select_pair(self, kin: Kinematics) -> int:
        """Choose the (object, environment) surface pair nearest to a placement."""
        if len(self._rel) > 1:
            best, best_cost = 0, math.inf
            for i in range(len(self._rel)):
                M = self.relative_pose(kin, i)
                cost = abs(M.translation[2] - self.margin) + 0.3 * np.linalg.norm(
                    pin.log3(M.rotation)[:2]
                )
                if cost < best_cost:
                    best, best_cost = i, cost
            self.pair = best
        return self.pair

    def _offset(self, kin: Kinematics, v6: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        key = (kin.version, id(kin), self.pair)
        if key != self._offset_key:
            self._offset_val = self._polygons[self.pair].offset(v6[0], v6[1])
            self._offset_key = key
        return self._offset_val

    def value(self, kin: Kinematics) -> np.ndarray:
        v6 = self._rel[self.pair].value6(kin)
        out = np.empty(5)
        out[:3] = v6[self.ROWS]
        out[3:] = self._offset(kin, v6)[0]
        return out

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        J6 = self._rel[self.pair].compute_jacobian(kin)
        J = np.empty((5, J6.shape[1]))
        J[:3] = J6[self.ROWS]
        D = self._offset(kin, self._rel[self.pair].value6(kin))[1]
        if D is None:
            J[3:] = 0.0
        else:
            J[3:] = D @ J6[:2]
        return J

    def inside(self, kin: Kinematics, tol: float = 1e-9) -> bool:
        """Is the object surface centre inside the environment polygon (pair = current)?"""
        M = self.relative_pose(kin)
        poly = self.pairs[self.pair][1].polygon_S
        return _inside_convex(poly, M.translation[0], M.translation[1], tol)


class _Polygon:
    """A convex polygon (k x 2, counter-clockwise) with its edges precomputed."""

    def __init__(self, poly: np.ndarray) -> None:
        self.a = np.asarray(poly, dtype=float)
        self.ab = np.roll(self.a, -1, axis=0) - self.a
        self.ab2 = np.einsum("ij,ij->i", self.ab, self.ab)
        n = np.column_stack([self.ab[:, 1], -self.ab[:, 0]])  # outward for CCW
        self.n = n / np.sqrt(self.ab2)[:, None]
        self._eye = np.eye(2)

    def offset(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray | None]:
        """(c - nearest point of the polygon, d/dc of it) with c = (x, y); (0, None) inside."""
        ca = np.array([x, y]) - self.a  # (k x 2)
        if (np.einsum("ij,ij->i", ca, self.n) <= 0.0).all():
            return np.zeros(2), None
        t = np.clip(np.einsum("ij,ij->i", ca, self.ab) / self.ab2, 0.0, 1.0)
        r = ca - t[:, None] * self.ab  # c - nearest point, per edge
        i = int(np.argmin(np.einsum("ij,ij->i", r, r)))
        D = self._eye if t[i] in (0.0, 1.0) else np.outer(self.n[i], self.n[i])
        return r[i], D


def _inside_convex(poly: np.ndarray, x: float, y: float, tol: float) -> bool:
    n = len(poly)
    sign = 0.0
    for i in range(n):
        ax, ay = poly[i]
        bx, by = poly[(i + 1) % n]
        c = (bx - ax) * (y - ay) - (by - ay) * (x - ax)
        if abs(c) <= tol:
            continue
        if sign == 0.0:
            sign = math.copysign(1.0, c)
        elif c * sign < 0:
            return False
    return True


class PlacementComplement(Constraint):
    """Where the object stands on its surface: [p_x, p_y, log3(R)_z] of :class:`Placement`'s M.

    Parametrised (thesis §3.2.1, g(q) = g0): along a transit path it keeps the object still.
    ``rhs_from`` also records the surface pair, stored as a 4th (non-error) entry of ``params``.
    The angle row is wrapped to (-pi, pi].
    """

    ROWS = np.array([True, True, False, False, False, True])

    def __init__(self, name: str, placement: Placement) -> None:
        super().__init__(name, 3, parametrised=True)
        self.placement = placement

    def joints(self) -> set[int]:
        return self.placement.joints()

    def to_dict(self, model: pin.Model) -> dict:
        out = super().to_dict(model)
        out.update({"placement": self.placement.name, "pair": self.placement.pair})
        return out

    def value(self, kin: Kinematics) -> np.ndarray:
        return self.placement._rel[self.placement.pair].value6(kin)[self.ROWS]

    def compute_error(self, kin: Kinematics) -> np.ndarray:
        e = self.value(kin) - self.rhs
        e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
        return e

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        return self.placement._rel[self.placement.pair].compute_jacobian(kin)[self.ROWS]


class ComPosition(Constraint):
    """Centre of mass in the frame of joint ``joint`` (offset ``M_JF``): e = p_com_F - rhs.

    Quasi-static balance of a humanoid (thesis §3.2.1, g_CoM): the CoM expressed in a foot frame
    stays put (rows x, y; z too when ``mask`` says so), parametrised or at a fixed target.
    d p_com_F / dv = R_WF^T (J_com - [J_F,lin in world] + [p_com - p_F]x J_F,ang in world).
    """

    def __init__(
        self,
        name: str,
        joint: int,
        M_JF: pin.SE3,
        target: np.ndarray | None = None,
        mask: Mask = (True, True, True),
        parametrised: bool = False,
    ) -> None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != (3,) or not m.any():
            raise ConstraintError(f"{name}: CoM mask has 3 entries, at least one true")
        super().__init__(name, int(m.sum()), parametrised)
        self.mask = m
        self.joint, self.M_JF = joint, M_JF
        self._Ad = M_JF.inverse().action
        if target is not None:
            self.rhs = np.asarray(target, dtype=float)[m].copy()

    def joints(self) -> set[int]:
        return set(range(1, 10**6))  # the CoM depends on every joint

    def to_dict(self, model: pin.Model) -> dict:
        out = super().to_dict(model)
        out.update(
            {
                "joint": model.names[self.joint],
                "M_JF": _pose_list(self.M_JF),
                "mask": [bool(v) for v in self.mask],
            }
        )
        return out

    def value(self, kin: Kinematics) -> np.ndarray:
        X_WF = kin.data.oMi[self.joint] * self.M_JF
        return X_WF.actInv(kin.com())[self.mask]

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        X_WF = kin.data.oMi[self.joint] * self.M_JF
        c = kin.com()
        Jc = kin.com_jacobian()
        if self.joint == 0:
            return (X_WF.rotation.T @ Jc)[self.mask]
        JF = self._Ad @ kin.joint_jacobian(self.joint)  # LOCAL in F
        # p_com_F = R^T (c - p). d/dt = R^T(c_dot - p_dot) - [w_F]x p_com_F,  p_dot = R v_F.
        pcF = X_WF.actInv(c)
        J = X_WF.rotation.T @ Jc - JF[:3] + np.cross(pcF, JF[3:].T).T
        return J[self.mask]


class ExplicitConstraint:
    """Explicit constraint: output joints' q are a function of other joints (substitution)."""

    name: str
    output_joint: int
    parametrised: bool = False

    def apply(self, kin: Kinematics, q: np.ndarray) -> None:
        """Write the output joint's q in place (``kin`` holds the forward kinematics of q)."""
        raise NotImplementedError

    def as_implicit(self) -> Constraint:
        raise NotImplementedError

    def input_joints(self) -> set[int]:
        return set()

    def to_dict(self, model: pin.Model) -> dict:
        return {"type": type(self).__name__, "output_joint": model.names[self.output_joint]}


class ExplicitRelativePose(ExplicitConstraint):
    """Free-flyer ``output_joint`` rigidly attached to a frame: X_WO = oMi[parent] * M_PO.

    Grasp of a handle H on a free-flying object O by gripper G (HPP ``createGrasp`` on a
    free-flyer): G = H  <=>  X_WO = X_WG M_OH^-1, so M_PO = M_PG M_OH^-1.  The object's body
    twist is V_O = Ad(M_PO^-1) V_P: the chain rule the projector uses for implicit constraints
    that depend on the object.  ``grasp_frames`` keep (parent, M_PG, object, M_OH) for
    :meth:`as_implicit`.
    """

    def __init__(
        self,
        name: str,
        model: pin.Model,
        output_joint: int,
        parent_joint: int,
        M_PG: pin.SE3,
        M_OH: pin.SE3,
    ) -> None:
        if model.joints[output_joint].nq != 7:
            raise ConstraintError(
                f"{name}: output joint {model.names[output_joint]} is not a free-flyer"
            )
        self.name = name
        self.output_joint = output_joint
        self.parent_joint = parent_joint
        self.M_PG, self.M_OH = M_PG, M_OH
        self.M_PO = M_PG * M_OH.inverse()
        self.Ad_OP = self.M_PO.inverse().action  # V_O = Ad_OP V_P
        self.idx_q = model.idx_qs[output_joint]
        self.idx_v = model.idx_vs[output_joint]

    def input_joints(self) -> set[int]:
        return {self.parent_joint}

    def to_dict(self, model: pin.Model) -> dict:
        """Grasp: gripper frame (parent_joint, M_PG) on handle frame (output_joint, M_OH)."""
        out = super().to_dict(model)
        out.update(
            {
                "parent_joint": model.names[self.parent_joint],
                "M_PG": _pose_list(self.M_PG),
                "M_OH": _pose_list(self.M_OH),
                "M_PO": _pose_list(self.M_PO),
            }
        )
        return out

    def pose(self, kin: Kinematics) -> pin.SE3:
        return kin.data.oMi[self.parent_joint] * self.M_PO

    def apply(self, kin: Kinematics, q: np.ndarray) -> None:
        q[self.idx_q : self.idx_q + 7] = pin.SE3ToXYZQUAT(self.pose(kin))

    def as_implicit(self) -> Constraint:
        return RelativeTransformation(
            self.name, self.parent_joint, self.M_PG, self.output_joint, self.M_OH
        )


class LockedJoint(ExplicitConstraint):
    """q[joint] = value (parametrised: ``value`` taken from a configuration by ``rhs_from``)."""

    parametrised = True

    def __init__(
        self, name: str, model: pin.Model, joint: int, value: np.ndarray | None = None
    ) -> None:
        self.name = name
        self.output_joint = joint
        self.model = model
        self.nq = model.joints[joint].nq
        self.nv = model.joints[joint].nv
        self.idx_q = model.idx_qs[joint]
        self.idx_v = model.idx_vs[joint]
        self.value = (
            np.asarray(value, dtype=float).copy()
            if value is not None
            else pin.neutral(model)[self.idx_q : self.idx_q + self.nq].copy()
        )
        if self.value.shape != (self.nq,):
            raise ConstraintError(f"{name}: value must have {self.nq} entries")

    def rhs_from_q(self, q: np.ndarray) -> None:
        self.value = q[self.idx_q : self.idx_q + self.nq].copy()

    def to_dict(self, model: pin.Model) -> dict:
        out = super().to_dict(model)
        out.update({"value": self.value.tolist(), "parametrised": bool(self.parametrised)})
        return out

    def apply(self, kin: Kinematics, q: np.ndarray) -> None:
        q[self.idx_q : self.idx_q + self.nq] = self.value

    def error(self, q: np.ndarray) -> float:
        """Distance of q's joint value to the locked value (quaternion sign-insensitive)."""
        a = q[self.idx_q : self.idx_q + self.nq]
        if self.nq == 7:
            dq = min(np.linalg.norm(a[3:] - self.value[3:]), np.linalg.norm(a[3:] + self.value[3:]))
            return float(np.linalg.norm(a[:3] - self.value[:3]) + dq)
        return float(np.linalg.norm(a - self.value))

    def as_implicit(self) -> Constraint:
        return _ImplicitLockedJoint(self)


class _ImplicitLockedJoint(Constraint):
    """Implicit form of a locked joint: e = log(q_locked^-1 q_joint) in the joint's tangent."""

    def __init__(self, locked: LockedJoint) -> None:
        super().__init__(locked.name, locked.nv)
        self.locked = locked

    def joints(self) -> set[int]:
        return {self.locked.output_joint}

    def value(self, kin: Kinematics) -> np.ndarray:
        lk = self.locked
        a = kin.q[lk.idx_q : lk.idx_q + lk.nq]
        if lk.nq == 7:
            return pin.log6(pin.XYZQUATToSE3(lk.value).actInv(pin.XYZQUATToSE3(a))).vector
        return a - lk.value

    def compute_jacobian(self, kin: Kinematics) -> np.ndarray:
        lk = self.locked
        J = np.zeros((lk.nv, kin.model.nv))
        if lk.nq == 7:
            a = kin.q[lk.idx_q : lk.idx_q + lk.nq]
            M = pin.XYZQUATToSE3(lk.value).actInv(pin.XYZQUATToSE3(a))
            J[:, lk.idx_v : lk.idx_v + 6] = pin.Jlog6(M)
        else:
            J[:, lk.idx_v : lk.idx_v + lk.nv] = np.eye(lk.nv)
        return J
