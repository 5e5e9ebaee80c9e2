"""Which limit of a finger joint closes the gripper, from the hand's geometry
(``marionette robot import``), and the lever arm through which its motor squeezes
(:meth:`Linkage.squeeze_lever_arm`, for the gripper admittance's force estimate).

A jaw closes onto the rest of the hand (the fixed jaw, the other finger, the palm between them)
and opens away from it, whatever its axis's sign: at its closed limit its surface lies nearer the
rest of the hand than at its open one. The measure is the mean distance from points drawn
uniformly over the jaw's collision surfaces (its visual ones when it has none) to the nearest point
of the surfaces rigidly attached to the link it is mounted on, at each limit (a margin inside);
the closed limit is the nearer one when the two means differ by more than ``DECISIVE_RATIO``.
Joints mimicking the finger follow it (a parallel gripper's second finger, a linkage), also
when a URDF made them fixed (then as their driver moves: about their axis for a hinge, along
it for a slide).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .urdf import Geometry, Joint, Urdf

DECISIVE_RATIO = 1.25  # the farther limit's mean distance over the nearer one's
TIP_FRACTION = 0.8  # a hinged jaw's tip: its points at least this fraction of its reach out
SURFACE_POINTS = 1500  # per geometry, drawn uniformly over its area (seeded)


@dataclass(frozen=True)
class Closing:
    """The guess: ``closed`` is "lower" or "upper", or None when the geometry cannot tell;
    ``distance`` the jaw's mean distance [m] to the rest of the hand at each limit."""

    closed: str | None
    distance: dict[str, float]


def closing_limit(urdf: Urdf, finger: Joint, margin: float) -> Closing:
    """Which limit of ``finger`` (revolute or prismatic, with both limits) closes it: see the
    module. ``urdf`` is the hand's URDF as written (its mimic joints movable: they follow the
    finger). ``margin`` is the fraction of the range the positions measured lie inside the
    limits."""
    from scipy.spatial import cKDTree

    assert finger.lower is not None and finger.upper is not None
    links = urdf.subtree(finger.parent)
    surfaces = {link: _surface(urdf, link) for link in links}
    jaw_links = set(urdf.subtree(finger.child))
    jaw = np.vstack([surfaces[link] for link in jaw_links])
    if not len(jaw) or not sum(len(surfaces[link]) for link in links if link not in jaw_links):
        return Closing(None, {})
    if finger.type != "prismatic":  # a hinged jaw's far end: its points farthest from the axis
        X = _poses(urdf, finger, 0.0)
        local = {
            link: _transform(np.linalg.inv(X[finger.child]) @ X[link], surfaces[link])
            for link in jaw_links
        }
    span = finger.upper - finger.lower
    distance = {}
    for limit, q in (
        ("lower", finger.lower + margin * span),
        ("upper", finger.upper - margin * span),
    ):
        X = _poses(urdf, finger, q)
        rest = np.vstack([_transform(X[k], surfaces[k]) for k in links if k not in jaw_links])
        points = np.vstack([_transform(X[k], surfaces[k]) for k in jaw_links])
        if finger.type != "prismatic":
            in_child = np.vstack([local[k] for k in jaw_links])
            axis = finger.axis / np.linalg.norm(finger.axis)
            radius = np.linalg.norm(in_child - np.outer(in_child @ axis, axis), axis=1)
            points = points[radius >= TIP_FRACTION * radius.max()]
        distance[limit] = float(np.mean(cKDTree(rest).query(points)[0]))
    near, far = sorted(distance, key=distance.__getitem__)
    decisive = distance[far] > DECISIVE_RATIO * distance[near]
    return Closing(near if decisive else None, distance)


@dataclass(frozen=True)
class Linkage:
    """A gripper's jaws as its finger joint moves them: ``jaws`` (the +y jaw's links, then the
    -y jaw's), moved by ``finger`` and the joints mimicking it, and the gripper frame
    ``X_link_gripper`` in ``gripper_link``."""

    urdf: Urdf
    finger: Joint
    jaws: tuple[tuple[str, ...], tuple[str, ...]]
    gripper_link: str
    X_link_gripper: np.ndarray

    def link_poses(self, q: float) -> dict[str, np.ndarray]:
        """The pose of each link the finger's parent carries, in the gripper frame, the finger
        at ``q`` and its mimics following it."""
        poses = _poses(self.urdf, self.finger, q)
        X_GP = np.linalg.inv(poses[self.gripper_link] @ self.X_link_gripper)
        return {link: X_GP @ X for link, X in poses.items()}

    def squeeze_lever_arm(self, q: float) -> float | None:
        """The motor torque per newton of squeeze [m] at ``q``: eq. 3.13's d_axis-gripper for
        any linkage, by virtual work. Each jaw presses the object at its point
        :meth:`pressing_points` finds, which closes at the speed v_j along the gripper's y axis
        per unit of finger motion, so tau dq = F (|v_+| + |v_-|) dq for a squeeze F on each
        side: the lever arm is |v_+| + |v_-| (a fixed jaw adds 0; two fingers on one slide give
        2, i.e. half the motor force per finger). None when :meth:`pressing_points` is."""
        points = self.pressing_points(q)
        if points is None:
            return None
        step = 1e-6  # [rad] or [m]
        poses, moved = _poses(self.urdf, self.finger, q), _poses(self.urdf, self.finger, q + step)
        X_GP = np.linalg.inv(poses[self.gripper_link] @ self.X_link_gripper)
        lever = 0.0
        for link, p in points:
            before = _transform(X_GP @ poses[link], p[None])[0]
            after = _transform(X_GP @ moved[link], p[None])[0]
            lever += abs(after[1] - before[1]) / step
        return lever

    @cached_property
    def _surfaces(self) -> dict[str, np.ndarray]:
        """Each jaw link's surface points (:func:`_surface`), drawn once."""
        return {link: _surface(self.urdf, link) for jaw in self.jaws for link in jaw}

    def opening(self, q: float) -> float | None:
        """The width [m] of an object centred on the gripper frame that the jaws touch with the
        finger at ``q``: the sum of each jaw's distance from the frame's origin to its
        :meth:`pressing_points` (a ball of that diameter, held where the grasp puts it). None
        when :meth:`pressing_points` is."""
        points = self.pressing_points(q)
        if points is None:
            return None
        poses = self.link_poses(q)
        return float(sum(np.linalg.norm(_transform(poses[link], p[None])[0]) for link, p in points))

    def position_for_width(self, width: float, lower: float, upper: float) -> float | None:
        """The finger position in [``lower``, ``upper``] (the stroke) at which the jaws close on
        an object ``width`` wide (:meth:`opening`), by bisection; None when the jaws cannot close
        on it (wider than the open jaws, narrower than the closed ones) or have no surfaces."""
        a, b = self.opening(lower), self.opening(upper)
        if a is None or b is None or not min(a, b) <= width <= max(a, b):
            return None
        lo, hi = (lower, upper) if a > b else (upper, lower)  # opening(lo) >= width >= opening(hi)
        for _ in range(30):  # a stroke of 1 rad to 1e-9
            mid = 0.5 * (lo + hi)
            value = self.opening(mid)
            if value is None:
                return None
            if value >= width:
                lo = mid
            else:
                hi = mid
        return 0.5 * (lo + hi)

    def pressing_points(self, q: float) -> list[tuple[str, np.ndarray]] | None:
        """Where each jaw presses a handle held at the gripper frame, the finger at ``q``:
        (link, point in that link's frame) of the jaw's collision surface point nearest the
        gripper frame's origin. None when the gripper's link is not carried by the finger's
        parent or a jaw has no surface."""
        poses = _poses(self.urdf, self.finger, q)
        if self.gripper_link not in poses:
            return None
        X_GP = np.linalg.inv(poses[self.gripper_link] @ self.X_link_gripper)
        out = []
        for jaw in self.jaws:
            surfaces = {link: self._surfaces[link] for link in jaw if link in poses}
            surfaces = {link: p for link, p in surfaces.items() if len(p)}
            if not surfaces:
                return None
            distance = {
                link: np.linalg.norm(_transform(X_GP @ poses[link], p), axis=1)
                for link, p in surfaces.items()
            }
            link = min(distance, key=lambda k: distance[k].min())
            out.append((link, surfaces[link][int(np.argmin(distance[link]))]))
        return out


def _poses(urdf: Urdf, finger: Joint, q: float) -> dict[str, np.ndarray]:
    """The pose of each link below ``finger``'s parent in the parent's frame, ``finger`` at
    ``q``, the joints mimicking it following it, every other joint at 0."""
    out = {finger.parent: np.eye(4)}
    stack = [finger.parent]
    while stack:
        parent = stack.pop()
        for j in urdf.child_joints(parent):
            value = 0.0
            if j.name == finger.name:
                value = q
            elif j.mimic is not None and j.mimic.joint == finger.name:
                value = j.mimic.multiplier * q + j.mimic.offset
            moves = j.type in ("revolute", "continuous", "prismatic") or j.mimic is not None
            # A mimic moves as its driver does (it slides with a slide), whatever type a URDF
            # gives it (fixed, for the controller's model).
            kind = finger.type if j.mimic is not None and j.mimic.joint == finger.name else j.type
            out[j.child] = out[parent] @ j.X_PJ @ (_motion(j, value, kind) if moves else np.eye(4))
            stack.append(j.child)
    return out


def _transform(X: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ X[:3, :3].T + X[:3, 3]


def _surface(urdf: Urdf, link: str) -> np.ndarray:
    """(N, 3) points drawn uniformly over ``link``'s collision surfaces (its visual ones when it
    has no collision geometry), in its frame."""
    import trimesh

    points = [np.zeros((0, 3))]
    for g in urdf.links[link].collisions or urdf.links[link].visuals:
        mesh = _mesh(g)
        if mesh is None or mesh.area <= 0:
            continue
        mesh.apply_transform(g.X_LG)
        points.append(trimesh.sample.sample_surface(mesh, SURFACE_POINTS, seed=0)[0])
    return np.vstack(points)


def _mesh(g: Geometry):
    import trimesh

    from marionette import robots

    if g.kind == "box":
        return trimesh.creation.box(g.size)
    if g.kind == "cylinder":
        return trimesh.creation.cylinder(radius=g.size[0], height=g.size[1])
    if g.kind == "sphere":
        return trimesh.creation.icosphere(radius=g.size[0])
    try:
        mesh = trimesh.load(robots.resolve_package_uri(g.filename), force="mesh")
    except (FileNotFoundError, ValueError):
        return None  # a missing mesh is the check's finding
    mesh.apply_scale(g.scale)
    return mesh


def _motion(joint: Joint, q: float, kind: str) -> np.ndarray:
    """The child frame in the joint frame at position ``q``: along the axis when ``kind`` is
    prismatic, about it otherwise."""
    X = np.eye(4)
    if kind == "prismatic":
        X[:3, 3] = joint.axis * q
        return X
    axis = joint.axis / np.linalg.norm(joint.axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    X[:3, :3] = np.eye(3) + np.sin(q) * K + (1 - np.cos(q)) * K @ K
    return X
