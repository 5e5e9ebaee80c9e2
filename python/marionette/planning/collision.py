"""Collision checking: configurations, and paths continuously (certified, as HPP "Dichotomy").

Geometry comes from the problem's Pinocchio ``GeometryModel`` (coal).  Link meshes are replaced
by their convex hulls: distance queries between convex shapes (GJK) are ~100x cheaper than
between triangle meshes, and a hull contains its mesh, so "free" stays free (conservative).

Continuous validation of a path segment q(t), t in [0, 1], linear in the free variables: a
point of body B moves at most u_B |dt| where
    u_B = sum over joints j between the root and B of |dq_j| r_jB
(r_jB bounds the distance from joint j's axis to any point of B: the translations of the
joints in between plus B's radius; free-flyers add their linear part).  A pair at distance d
at time t is therefore collision-free on |t' - t| < d / (u_A + u_B): each pair keeps its own
certified horizon and only the pairs whose horizon has run out are queried again.  Pairs that
the transition keeps rigid (both bodies attached to the same joint through explicit or full
6-D constraints, or both still) are checked at the start only.

On a free motion (a transit or a transfer, not an approach), a pair of a moving body and a still
one (the robot or what it carries against the table, an object put down, the environment) keeps
a clearance (``CLEARANCE``) instead of contact: the same stepping with d - clearance. So does an
object the robot carries against the robot's other bodies (the other arm, the torso): a robot
tracks a plan within millimetres, and a servo moves the hand that holds an object by what the
camera measures, so a free hand planned to graze the object the other hand carries strikes it
(a friction plank flip: the right hand, open and leaving, pushed the plank 19 mm / 10 deg in the
left hand).  A path is excused, pair by pair, where one of its ends is already closer (a given
start, goal or waypoint placed close); every configuration the planners and the optimiser create
(an extension's end, whether stopped or at its random target, a leaf planner's node, a
shortcut's cut) keeps the clearance (:meth:`CollisionChecker.is_clear`), so the excuse never
spreads from the given ones.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import coal
import numpy as np
import pinocchio as pin

from marionette.planning.constraints import (
    RelativeTransformation,
)
from marionette.planning.problem import ManipulationProblem

if TYPE_CHECKING:
    from marionette.planning.path import ConstrainedPath
    from marionette.planning.projector import Projector


# Two bodies closer than this [m] are in contact: counted as a collision (HPP's tolerance 0
# up to a micrometre), which also bounds the certified steps from below.
CONTACT = 1e-6
MAX_QUERIES = 20000  # evaluations of one segment before it is refused as grazing
# A pair whose bounding spheres are this far apart [m] is certified from that lower bound of
# its distance, without a GJK query (same in cpp/src/planning/path_validator.cc).
SPHERE_MARGIN = 0.02
# On a free motion (a transit or transfer, not an approach) the robots and what they carry stay
# this far [m] from what stays in place (the problem's ``planner: clearance``). With contact
# only, paths grazed the table: roadmap nodes sat where an extension was stopped by it (0.06 mm)
# and shortcuts pulled motions tight against it (0.2 mm); a humanoid tracking such a plan within
# a few millimetres pressed its fingertips on the table and slid its feet.
CLEARANCE = 0.01


def convexify(geom_model: pin.GeometryModel) -> pin.GeometryModel:
    """Copy of ``geom_model`` whose triangle meshes are replaced by their convex hulls."""
    out = geom_model.copy()
    for o in out.geometryObjects:
        g = o.geometry
        if isinstance(g, coal.BVHModelBase):
            g.buildConvexHull(True, "Qt")
            o.geometry = g.convex
    return out


def _radius(geom: pin.GeometryObject) -> float:
    """Upper bound of the distance from the parent joint origin to any point of the geometry."""
    g = geom.geometry
    g.computeLocalAABB()
    aabb = g.aabb_local
    corners = np.array(
        [
            [x, y, z]
            for x in (aabb.min_[0], aabb.max_[0])
            for y in (aabb.min_[1], aabb.max_[1])
            for z in (aabb.min_[2], aabb.max_[2])
        ]
    )
    pts = corners @ geom.placement.rotation.T + geom.placement.translation
    return float(np.max(np.linalg.norm(pts, axis=1)))


class CollisionChecker:
    """Configuration and path validation for one problem (one instance per thread)."""

    def __init__(
        self, problem: ManipulationProblem, convex: bool = True, backend: str = "cpp"
    ) -> None:
        """``backend``: "cpp" runs path validation in ``marionette._core.planning`` (same
        certified algorithm and tolerance, ~10x faster), "python" in :meth:`_certified`."""
        if backend not in ("cpp", "python"):
            raise ValueError(f"backend must be 'cpp' or 'python', got {backend!r}")
        self.problem = problem
        self.backend = backend
        self.clearance = float((problem.settings.get("planner") or {}).get("clearance", CLEARANCE))
        self.model = problem.model
        self.geom_model = convexify(problem.geom_model) if convex else problem.geom_model.copy()
        self.data = self.model.createData()
        self.geom_data = pin.GeometryData(self.geom_model)
        self.pairs = [(cp.first, cp.second) for cp in self.geom_model.collisionPairs]
        objs = self.geom_model.geometryObjects
        self.geom_joint = [o.parentJoint for o in objs]
        self.geom_radius = [_radius(o) for o in objs]
        self._sphere_centre, self._sphere_radius = [], []
        for o in objs:
            o.geometry.computeLocalAABB()
            self._sphere_centre.append(np.array(o.geometry.aabb_center))
            self._sphere_radius.append(float(o.geometry.aabb_radius))
        m = self.model
        # chain_r[g]: list of (joint, r_jg) for every joint j on g's kinematic chain.
        self.chains = [
            self._chain(self.geom_joint[g], self.geom_radius[g]) for g in range(len(objs))
        ]
        self.checks = 0  # number of pair queries (statistics)
        self.refused_grazing = 0
        self._motion_cache: dict[int, tuple] = {}
        self._grasp_pairs: dict[tuple, frozenset[int]] = {}
        self._object_pairs: dict[str, np.ndarray] = {}
        self._joint_kinds = []  # (joint, idx_v, 0 revolute-like | 1 prismatic | 2 free-flyer)
        for j in range(1, m.njoints):
            jm = m.joints[j]
            if jm.nv == 6:
                self._joint_kinds.append((j, m.idx_vs[j], 2))
            elif jm.nv == 1:
                self._joint_kinds.append(
                    (j, m.idx_vs[j], 1 if "Prismatic" in jm.shortname() else 0)
                )
            else:
                raise ValueError(f"joint {m.names[j]} ({jm.shortname()}) is not supported")
        kinds = self._joint_kinds
        self._rev_j = np.array([j for j, _, k in kinds if k == 0], dtype=int)
        self._rev_v = np.array([iv for _, iv, k in kinds if k == 0], dtype=int)
        self._pri_j = np.array([j for j, _, k in kinds if k == 1], dtype=int)
        self._pri_v = np.array([iv for _, iv, k in kinds if k == 1], dtype=int)
        self._ff = [(j, iv) for j, iv, k in kinds if k == 2]
        self._cpp = None
        self._cpp_motion: dict[tuple, tuple] = {}
        if backend == "cpp":
            from marionette.planning import collision_cpp

            self._cpp = collision_cpp.build_validator(
                self.model, self.geom_model, self.pairs, CONTACT, MAX_QUERIES
            )

    def _chain(self, joint: int, radius: float) -> list[tuple[int, float]]:
        m = self.model
        out = []
        r = radius
        j = joint
        while j > 0:
            out.append((j, r))
            r += float(np.linalg.norm(m.jointPlacements[j].translation))
            j = m.parents[j]
        return out

    # --------------------------------------------------------------------------- grasp contacts
    def grasp_contact_pairs(self, grasps: dict[str, str]) -> frozenset[int]:
        """Pairs between a gripper's body (the geometries on the gripper frame's joint and the
        joints below it: fingers) and the object whose handle it grasps: contact there is the
        grasp itself, not a collision."""
        key = tuple(sorted(grasps.items()))
        cached = self._grasp_pairs.get(key)
        if cached is not None:
            return cached
        p = self.problem
        out = set()
        m = self.model
        for g, h in key:
            gj = p.grippers[g].joint_id
            hand = {j for j in range(m.njoints) if gj in _ancestors_incl(m, j)}
            oj = p.objects[p.handles[h].object].joint_id
            for k, (a, b) in enumerate(self.pairs):
                ja, jb = self.geom_joint[a], self.geom_joint[b]
                if (ja in hand and jb == oj) or (jb in hand and ja == oj):
                    out.add(k)
        res = frozenset(out)
        self._grasp_pairs[key] = res
        return res

    # --------------------------------------------------------------------------- configurations
    def is_valid(self, q: np.ndarray, allowed: frozenset[int] = frozenset()) -> bool:
        """No pair in collision at q, except the ``allowed`` ones (grasp contacts)."""
        if not allowed:
            return not pin.computeCollisions(
                self.model, self.data, self.geom_model, self.geom_data, q, True
            )
        gd = self.geom_data
        for k in allowed:
            gd.deactivateCollisionPair(k)
        try:
            return not pin.computeCollisions(self.model, self.data, self.geom_model, gd, q, True)
        finally:
            for k in allowed:
                gd.activateCollisionPair(k)

    def object_pairs(self, obj: str) -> np.ndarray:
        """Pair indices between object ``obj`` and what is not a robot (other objects, the
        environment): where an object can be put down does not depend on the robots."""
        cached = self._object_pairs.get(obj)
        if cached is None:
            oj = self.problem.objects[obj].joint_id
            robot = set(self.problem.robot_joint_ids)
            cached = np.array(
                [
                    k
                    for k, (a, b) in enumerate(self.pairs)
                    if oj in (self.geom_joint[a], self.geom_joint[b])
                    and self.geom_joint[a] not in robot
                    and self.geom_joint[b] not in robot
                ],
                dtype=int,
            )
            self._object_pairs[obj] = cached
        return cached

    def objects_collide(self, q: np.ndarray, objects: list[str]) -> bool:
        """Is one of ``objects`` in collision with another object or the environment at q?"""
        pairs = np.unique(np.concatenate([self.object_pairs(o) for o in objects]))
        if not len(pairs):
            return False
        self._update(q)
        return any(pin.computeCollision(self.geom_model, self.geom_data, int(k)) for k in pairs)

    def colliding_pairs(self, q: np.ndarray) -> list[tuple[str, str]]:
        """Names of the pairs in collision at q (for error messages)."""
        pin.computeCollisions(self.model, self.data, self.geom_model, self.geom_data, q, False)
        names = [o.name for o in self.geom_model.geometryObjects]
        return [
            (names[a], names[b])
            for k, (a, b) in enumerate(self.pairs)
            if self.geom_data.collisionResults[k].isCollision()
        ]

    # --------------------------------------------------------------------------- paths
    def _motion(
        self, projector: Projector
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per pair, how fast it can close its distance, as linear maps of joint speeds.

        Returns (rigid (npairs,) bool, R (npairs x njoints), L (npairs x njoints), keeps
        (npairs,) bool) with u_pair = R @ angular_speed + L @ linear_speed; ``keeps``: the pairs
        that keep the clearance on a free motion — one body stays in place in this transition
        and the other moves, or one is an object (carried: it moves with another body).  A locked
        joint is welded to its parent: its geometries move with the nearest joint above it that
        is not locked (an object locked where it rests: with the universe, still; a locked
        finger: with the wrist).  A geometry on an object attached by an explicit relative pose
        moves with the parent joint.  Joints common to both chains move the pair rigidly and are
        left out (HPP's body-pair bound); pairs attached to one (welded) joint are rigid.
        """
        key = id(projector)
        cached = self._motion_cache.get(key)
        if cached is not None and cached[0] is projector:
            return cached[1]
        eff = list(self.geom_joint)
        chains = list(self.chains)
        rel = {e.output_joint: e for e in projector.relative}
        locked = {lk.output_joint for lk in projector.locked}
        rigid_map = _rigid_groups(self.model, projector)
        m = self.model

        def welded(j: int, r: float) -> tuple[int, float]:
            """The joint that moves joint j's bodies, and the radius grown on the way up."""
            while j in locked:
                r += float(np.linalg.norm(m.jointPlacements[j].translation))
                j = m.parents[j]
            return j, r

        for g, j in enumerate(self.geom_joint):
            r = self.geom_radius[g]
            if j in rel:
                e = rel[j]
                j, r = e.parent_joint, r + float(np.linalg.norm(e.M_PO.translation))
            j, r = welded(j, r)
            if j != self.geom_joint[g]:
                eff[g], chains[g] = j, (self._chain(j, r) if j > 0 else [])
        n = len(self.pairs)
        nj = self.model.njoints
        objects = {o.joint_id for o in self.problem.objects.values()}
        on_object = [j in objects for j in self.geom_joint]
        rigid = np.zeros(n, dtype=bool)
        R = np.zeros((n, nj))
        L = np.zeros((n, nj))
        keeps = np.zeros(n, dtype=bool)
        for k, (a, b) in enumerate(self.pairs):
            ga, gb = rigid_map.get(eff[a], eff[a]), rigid_map.get(eff[b], eff[b])
            if ga == gb:
                rigid[k] = True
                continue
            keeps[k] = (ga == 0) != (gb == 0) or on_object[a] or on_object[b]
            common = {j for j, _ in chains[a]} & {j for j, _ in chains[b]}
            for j, r in chains[a] + chains[b]:
                if j not in common:
                    R[k, j] += r
                    L[k, j] += 1.0
        out = (rigid, R, L, keeps)
        self._motion_cache[key] = (projector, out)
        return out

    def validate(
        self, path: ConstrainedPath, allowed: frozenset[int] | None = None, prefix: bool = True
    ) -> tuple[bool, float]:
        """(fully valid, s_valid): the path is collision-free on [0, s_valid] (arc length).

        Progressive certified validation, segment by segment of the path's polyline.  Pairs in
        ``allowed`` (default: the grasp contacts of the path's transition) are not checked.
        ``prefix=False`` (connections, shortcuts: all or nothing) first probes a few
        configurations and gives up at the first collision found, s_valid then being 0."""
        if allowed is None:
            allowed = self.grasp_contact_pairs(path.edge.grasps)
        free_motion = not path.edge.short
        if self._cpp is not None:
            return self._validate_cpp(self._cpp, path, allowed, free_motion, prefix)
        rigid, R, L, _ = self._motion(path.projector)
        clearance = self._clearance(path.projector, free_motion)
        if allowed:
            rigid = rigid.copy()
            rigid[list(allowed)] = True  # treated as never moving...
            skip = np.zeros(len(self.pairs), dtype=bool)
            skip[list(allowed)] = True  # ...and never checked
        else:
            skip = None
        if not prefix:
            # All or nothing: cheap discrete probes (dichotomy order) reject most colliding
            # paths before any certified stepping.
            for frac in (0.5, 0.25, 0.75):
                if not self.is_valid(path.eval(frac * path.length), allowed):
                    return False, 0.0
        return self._certified(path, rigid, R, L, skip, clearance)

    def _clearance(self, projector: Projector, free_motion: bool) -> np.ndarray:
        """The distance each pair keeps on a path of this transition [m] (npairs): the
        clearance for a moving body against a still one on a free motion, else contact."""
        out = np.full(len(self.pairs), CONTACT)
        if free_motion and self.clearance > CONTACT:
            out[self._motion(projector)[3]] = self.clearance
        return out

    def is_clear(self, q: np.ndarray, path: ConstrainedPath) -> bool:
        """Does q, a configuration of ``path``'s transition, keep that transition's clearance
        (:meth:`_clearance`; grasp contacts excepted)? What every configuration a planner or an
        optimiser adds on a free motion must keep: a path is excused from the clearance only at
        an end already closer (a given start, goal or waypoint)."""
        allowed = self.grasp_contact_pairs(path.edge.grasps)
        free_motion = not path.edge.short
        if self._cpp is not None:
            _, motion, _ = self._cpp_pair_motion(path.projector, allowed, free_motion)
            return bool(self._cpp.is_clear(np.asarray(q, dtype=float), motion))
        keep = self._clearance(path.projector, free_motion)
        self._update(q)
        return all(
            self._distance_within(k, keep[k]) > keep[k]
            for k in range(len(self.pairs))
            if k not in allowed
        )

    def _distance_within(self, k: int, within: float) -> float:
        """Distance of pair k at the last update: exact (GJK) only when its bounding spheres are
        closer than ``within``, else their lower bound (PathValidator::DistanceWithin)."""
        bound = self._sphere_bounds(np.array([k]))[0]
        if bound > within:
            return float(bound)
        return pin.computeDistance(self.geom_model, self.geom_data, k).min_distance

    def _cpp_pair_motion(
        self, projector: Projector, allowed: frozenset[int], free_motion: bool
    ) -> tuple:
        """(projector, C++ PairMotion, attached parts) of a transition (its paths free motions
        or approaches: :meth:`_clearance`), cached."""
        from marionette.planning import collision_cpp

        key = (id(projector), allowed, free_motion)
        cached = self._cpp_motion.get(key)
        if cached is None or cached[0] is not projector:
            rigid, R, L, _ = self._motion(projector)
            skip = np.zeros(len(self.pairs), dtype=bool)
            skip[list(allowed)] = True
            clearance = self._clearance(projector, free_motion)
            motion = collision_cpp._planning.PairMotion(rigid, skip, R, L, clearance)
            cached = (projector, motion, collision_cpp.attached(projector))
            self._cpp_motion[key] = cached
        return cached

    # --------------------------------------------------------------------------- leaf planning
    def leaf_free_joints(self, projector: Projector) -> np.ndarray | None:
        """q indices of a leaf's free variables when the leaf is the space of its free 1-dof
        joints (every constraint explicit: locked joints, attached objects), else None."""
        if projector.implicit or self._cpp is None:
            return None
        m = self.model
        out = []
        for j in range(1, m.njoints):
            iv, nv = m.idx_vs[j], m.joints[j].nv
            if not projector.free[iv : iv + nv].any():
                continue
            if nv != 1 or m.joints[j].nq != 1:
                return None
            out.append(m.idx_qs[j])
        return np.asarray(out, dtype=int) if out else None

    def plan_in_leaf(
        self,
        projector: Projector,
        allowed: frozenset[int],
        q1: np.ndarray,
        q2: np.ndarray,
        seed: int,
        max_iterations: int = 200,
        max_time_s: float = 1.0,
        step: float = 0.1,
    ) -> np.ndarray | None:
        """Waypoints (k x nq) of a collision-free polyline q1 -> q2 inside the leaf of
        ``projector`` (right-hand sides already set from q1), by RRT-Connect in C++
        (cpp/include/marionette/planning/leaf_planner.h): OMPL's in a space of free joints
        (:meth:`leaf_free_joints`), a projecting one (nodes at most ``step`` apart) on a leaf
        with implicit constraints; None when not found."""
        from marionette.planning import collision_cpp

        if projector.implicit:
            return self._plan_in_constrained_leaf(
                projector, allowed, q1, q2, seed, max_iterations, max_time_s, step
            )
        free = self.leaf_free_joints(projector)
        if free is None or self._cpp is None:  # (no free joints without the C++ backend)
            return None
        _, motion, attached = self._cpp_pair_motion(projector, allowed, free_motion=True)
        sub = collision_cpp._planning.Substitution(
            [lk.idx_q for lk in projector.locked],
            [lk.value.copy() for lk in projector.locked],
            *attached,
        )
        solved, waypoints, _it, queries = self._cpp.plan_in_leaf(
            motion,
            np.asarray(q1, dtype=float),
            np.asarray(q2, dtype=float),
            [int(i) for i in free],
            self.problem.lower[free],
            self.problem.upper[free],
            sub,
            int(max_iterations),
            float(max_time_s),
            0.0,
            int(seed) & 0xFFFFFFFF,
        )
        self.checks += queries
        return np.asarray(waypoints) if solved else None

    def _plan_in_constrained_leaf(
        self, projector, allowed, q1, q2, seed, max_iterations, max_time_s, step
    ) -> np.ndarray | None:
        from marionette.planning import collision_cpp

        if projector._cpp is None or self._cpp is None:
            return None
        _, motion, attached = self._cpp_pair_motion(projector, allowed, free_motion=True)
        sub = collision_cpp._planning.Substitution(
            [lk.idx_q for lk in projector.locked],
            [lk.value.copy() for lk in projector.locked],
            *attached,
        )
        # Samples: the free variables' q entries (1-dof joints, free-flyer translations), in
        # the bounds and within one unit (rad, m) of the two ends: a connection is local.
        m = self.model
        free_q: list[int] = []
        for j in range(1, m.njoints):
            iv, nv = m.idx_vs[j], m.joints[j].nv
            if not projector.free[iv : iv + nv].any():
                continue
            iq = m.idx_qs[j]
            free_q += [iq] if nv == 1 else list(range(iq, iq + 3)) if nv == 6 else []
        idx = np.asarray(free_q, dtype=int)
        lo = np.maximum(self.problem.lower[idx], np.minimum(q1[idx], q2[idx]) - 1.0)
        hi = np.minimum(self.problem.upper[idx], np.maximum(q1[idx], q2[idx]) + 1.0)
        cpp = projector._cpp
        solved, waypoints, _it, queries = collision_cpp._planning.plan_in_constrained_leaf(
            self._cpp,
            cpp.cpp,
            motion,
            np.asarray(q1, dtype=float),
            np.asarray(q2, dtype=float),
            cpp.rhs(),
            cpp.pairs(),
            [int(i) for i in idx],
            lo,
            hi,
            sub,
            float(step),
            float(projector.error_threshold),
            int(projector.max_iterations),
            int(max_iterations),
            float(max_time_s),
            int(seed) & 0xFFFFFFFF,
        )
        self.checks += queries
        if not solved:
            return None
        pts = np.asarray(waypoints)
        keep = np.concatenate([[True], np.any(np.diff(pts, axis=0) != 0.0, axis=1)])
        return pts[keep]

    def _validate_cpp(
        self,
        validator: Any,
        path: ConstrainedPath,
        allowed: frozenset[int],
        free_motion: bool,
        prefix: bool,
    ) -> tuple[bool, float]:
        """:meth:`validate` in C++: the pair bounds, clearances and explicit constraints handed
        over once per (transition projector, allowed pairs, free motion or not), the locked
        values once per path; ``validator``: the C++ path validator (``self._cpp``)."""
        from marionette.planning import collision_cpp

        projector = path.projector
        _, motion, attached = self._cpp_pair_motion(projector, allowed, free_motion)
        ok, s, queries, grazing = validator.validate(
            path.points, path.cum, collision_cpp.substitution(path, attached), motion, not prefix
        )
        self.checks += queries
        self.refused_grazing += grazing
        # The Python evaluation leaves the path's right-hand sides in its projector: keep that.
        projector.restore_rhs(path.rhs_state)
        return ok, s

    def _certified(
        self,
        path: ConstrainedPath,
        rigid: np.ndarray,
        R: np.ndarray,
        L: np.ndarray,
        skip: np.ndarray | None,
        clearance: np.ndarray,
    ) -> tuple[bool, float]:
        # The distance each pair keeps on this path: its clearance, or contact where an end of
        # the path is already closer (a given start, goal or waypoint placed close).
        threshold = np.where(rigid if skip is None else rigid | skip, CONTACT, clearance)
        for q_end in (path.points[0], path.points[-1]):
            kept = np.flatnonzero(threshold > CONTACT)
            if not kept.size:
                break
            self._update(q_end)
            for k in kept:
                if self._distance_within(int(k), threshold[k]) <= threshold[k]:
                    threshold[k] = CONTACT
        q0 = path.eval(0.0)
        self._update(q0)
        # Pairs that do not move relatively: checked once, at the start.
        for k in np.flatnonzero(rigid if skip is None else rigid & ~skip):
            self.checks += 1
            if pin.computeCollision(self.geom_model, self.geom_data, int(k)):
                return False, 0.0
        pts = path.points
        # Certified displacement left to each pair (0: query it); carried from segment to
        # segment of a polyline so that a projected path is not re-queried at every vertex.
        budget = np.zeros(len(self.pairs))
        for i in range(len(pts) - 1):
            s0, s1 = path.cum[i], path.cum[i + 1]
            ok, t = self._validate_segment(
                path, pts[i], pts[i + 1], s0, s1, rigid, R, L, budget, threshold
            )
            if not ok:
                return False, s0 + t * (s1 - s0)
        return True, path.length

    def _joint_speeds(self, qa: np.ndarray, qb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(angular, linear) displacement of each joint over the segment (per unit t)."""
        m = self.model
        dv = pin.difference(m, qa, qb)
        ang = np.zeros(m.njoints)
        lin = np.zeros(m.njoints)
        ang[self._rev_j] = np.abs(dv[self._rev_v])
        lin[self._pri_j] = np.abs(dv[self._pri_v])
        for j, iv in self._ff:
            lin[j] = math.sqrt(dv[iv] ** 2 + dv[iv + 1] ** 2 + dv[iv + 2] ** 2)
            ang[j] = math.sqrt(dv[iv + 3] ** 2 + dv[iv + 4] ** 2 + dv[iv + 5] ** 2)
        return ang, lin

    def _update(self, q: np.ndarray) -> None:
        pin.updateGeometryPlacements(self.model, self.data, self.geom_model, self.geom_data, q)

    def _sphere_bounds(self, pairs: np.ndarray) -> np.ndarray:
        """Lower bounds of the distances of ``pairs`` at the last update: |c_a - c_b| - r_a - r_b
        from the geometries' bounding spheres."""
        oMg = self.geom_data.oMg
        centres = {g: oMg[g].act(self._sphere_centre[g]) for k in pairs for g in self.pairs[int(k)]}
        return np.array(
            [
                np.linalg.norm(centres[a] - centres[b])
                - self._sphere_radius[a]
                - self._sphere_radius[b]
                for a, b in (self.pairs[int(k)] for k in pairs)
            ]
        )

    def _validate_segment(
        self, path, qa, qb, s0, s1, rigid, R, L, budget: np.ndarray, threshold: np.ndarray
    ) -> tuple[bool, float]:
        """Certified check of the segment qa -> qb (t in [0, 1]); (ok, first unsafe t).
        ``budget`` (npairs): certified displacement left per pair, updated in place;
        ``threshold`` (npairs): the distance each pair keeps."""
        ang, lin = self._joint_speeds(qa, qb)
        u = R @ ang + L @ lin
        moving = (u > 0.0) & ~rigid
        if not moving.any():
            return True, 1.0
        horizon = np.full(len(u), np.inf)  # t up to which each pair is certified
        horizon[moving] = budget[moving] / u[moving]
        t = 0.0
        length = s1 - s0
        gm, gd = self.geom_model, self.geom_data
        for _ in range(MAX_QUERIES):
            # Pairs due within the next 1 % of the segment are refreshed now as well: an early
            # query only restarts their certified interval sooner (still contiguous), and one
            # forward kinematics then serves several pairs.
            due = np.flatnonzero(horizon <= t + 0.01)
            if due.size:
                q = path.eval(s0 + t * length)
                self._update(q)
                # Pairs whose bounding spheres are far apart are certified by that bound.
                d = self._sphere_bounds(due)
                keep = threshold[due]
                for i in np.flatnonzero(d <= SPHERE_MARGIN + keep):
                    self.checks += 1
                    d[i] = pin.computeDistance(gm, gd, int(due[i])).min_distance
                    if d[i] <= keep[i]:
                        return False, t
                horizon[due] = t + (d - keep) / u[due]
            t_next = float(horizon.min())
            if t_next >= 1.0:
                budget[moving] = (horizon[moving] - 1.0) * u[moving]
                return True, 1.0
            # d > threshold at every query; a pair hugging it ends in the query budget.
            t = t_next
        # Bodies grazing each other along the whole segment: not certifiable, refused.
        self.refused_grazing += 1
        return False, t


def _ancestors_incl(model: pin.Model, joint: int) -> set[int]:
    out = set()
    while joint > 0:
        out.add(joint)
        joint = model.parents[joint]
    return out


def _rigid_groups(model: pin.Model, projector: Projector) -> dict[int, int]:
    """Joints welded together by full 6-D relative transformations of the projector
    (constant rhs along a path): maps joint -> representative joint (union-find)."""
    parent: dict[int, int] = {}

    def find(a: int) -> int:
        while parent.get(a, a) != a:
            a = parent[a]
        return a

    for c in projector.implicit:
        if isinstance(c, RelativeTransformation) and c.mask.all():
            a, b = find(c.joint1), find(c.joint2)
            if a != b:
                parent[max(a, b)] = min(a, b)
    return {j: find(j) for j in list(parent)}
