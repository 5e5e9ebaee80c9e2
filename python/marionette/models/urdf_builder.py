"""Write simple URDFs (primitive shapes, fixed joints) from Python, deterministically."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from .xml_util import fmt, fmt_vec, indent_and_serialize, matrix_to_rpy, sub


@dataclass
class Shape:
    """A primitive: ``kind`` box (size = full extents), cylinder (radius, length along z) or
    sphere (radius,), placed by ``X`` (4 x 4) in its link."""

    kind: str
    size: tuple[float, ...]
    X: np.ndarray = field(default_factory=lambda: np.eye(4))
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    collision: bool = True  # False: visual only (markings)
    name: str | None = None

    def volume(self) -> float:
        if self.kind == "box":
            return float(np.prod(self.size))
        if self.kind == "cylinder":
            return float(np.pi * self.size[0] ** 2 * self.size[1])
        return float(4.0 / 3.0 * np.pi * self.size[0] ** 3)

    def inertia_about_centre(self, mass: float) -> np.ndarray:
        """(3, 3) rotational inertia of a solid of ``mass`` about its centre, shape axes."""
        if self.kind == "box":
            a, b, c = self.size
            return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
        if self.kind == "cylinder":
            r, h = self.size
            i = mass * (3 * r * r + h * h) / 12.0
            return np.diag([i, i, mass * r * r / 2.0])
        r = self.size[0]
        return np.eye(3) * 0.4 * mass * r * r


def rigid_inertia(shapes: list[Shape], density: float) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass, com (3,), inertia about the com (3, 3)) of solid ``shapes`` of one density.

    Composite body: masses add, the com is the mass-weighted mean, and each shape's inertia
    is rotated into the link frame and moved to the com (parallel-axis theorem).
    """
    solid = [s for s in shapes if s.collision]
    masses = [density * s.volume() for s in solid]
    mass = float(sum(masses))
    com = np.zeros(3)
    for m, s in zip(masses, solid):
        com = com + m * s.X[:3, 3]
    com /= mass
    inertia = np.zeros((3, 3))
    for m, s in zip(masses, solid):
        R = s.X[:3, :3]
        d = s.X[:3, 3] - com
        inertia += R @ s.inertia_about_centre(m) @ R.T + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, inertia


class UrdfBuilder:
    """Accumulates links and joints (fixed, prismatic), then serializes the URDF."""

    def __init__(self, name: str, comment: str, root: ET.Element | None = None) -> None:
        """A new URDF, or (``root`` given) additions to a parsed one."""
        self.root = root if root is not None else ET.Element("robot", name=name)
        self.comment = comment

    def link(
        self,
        name: str,
        shapes: list[Shape],
        mass: float | None = None,
        density: float | None = None,
    ) -> None:
        """A link of ``shapes``; inertia from ``density`` (or ``mass`` spread uniformly)."""
        link = sub(self.root, "link", name=name)
        if shapes and density is None and mass:
            density = mass / sum(s.volume() for s in shapes if s.collision)
        if shapes and density:
            m, com, inertia = rigid_inertia(shapes, density)
            ie = sub(link, "inertial")
            sub(ie, "origin", xyz=fmt_vec(com), rpy="0 0 0")
            sub(ie, "mass", value=fmt(m))
            sub(
                ie,
                "inertia",
                ixx=fmt(inertia[0, 0]),
                ixy=fmt(inertia[0, 1]),
                ixz=fmt(inertia[0, 2]),
                iyy=fmt(inertia[1, 1]),
                iyz=fmt(inertia[1, 2]),
                izz=fmt(inertia[2, 2]),
            )
        for s in shapes:
            self._geometry(link, "visual", s)
            if s.collision:
                self._geometry(link, "collision", s)

    def fixed_joint(
        self,
        name: str,
        parent: str,
        child: str,
        X: np.ndarray,
        mimic: str | None = None,
        axis: tuple[float, float, float] | None = None,
    ) -> None:
        """A fixed joint; ``mimic`` names the joint it follows (multiplier 1, offset 0) along
        ``axis`` where the simulation moves it (reduced humanoid URDFs declare their fingers
        the same way: Pinocchio keeps them fixed, the MJCF ties them to their driver)."""
        j = sub(self.root, "joint", name=name, type="fixed")
        sub(j, "parent", link=parent)
        sub(j, "child", link=child)
        _origin(j, X)
        if mimic is not None:
            if axis is None:
                raise ValueError(f"fixed joint {name} mimics {mimic}: give the axis it moves along")
            sub(j, "axis", xyz=fmt_vec(axis))
            sub(j, "mimic", joint=mimic, multiplier="1", offset="0")

    def prismatic_joint(
        self,
        name: str,
        parent: str,
        child: str,
        X: np.ndarray,
        axis: tuple[float, float, float],
        lower: float,
        upper: float,
        effort: float,
        velocity: float,
    ) -> None:
        j = sub(self.root, "joint", name=name, type="prismatic")
        sub(j, "parent", link=parent)
        sub(j, "child", link=child)
        _origin(j, X)
        sub(j, "axis", xyz=fmt_vec(axis))
        sub(
            j,
            "limit",
            lower=fmt(lower),
            upper=fmt(upper),
            effort=fmt(effort),
            velocity=fmt(velocity),
        )

    def text(self) -> str:
        return indent_and_serialize(self.root, self.comment)

    @staticmethod
    def _geometry(link: ET.Element, tag: str, s: Shape) -> None:
        g = sub(link, tag, name=s.name)
        _origin(g, s.X)
        geo = sub(g, "geometry")
        if s.kind == "box":
            sub(geo, "box", size=fmt_vec(s.size))
        elif s.kind == "cylinder":
            sub(geo, "cylinder", radius=fmt(s.size[0]), length=fmt(s.size[1]))
        elif s.kind == "sphere":
            sub(geo, "sphere", radius=fmt(s.size[0]))
        else:
            raise ValueError(f"unknown shape kind {s.kind!r}")
        if tag == "visual":
            m = sub(g, "material", name=f"rgba_{fmt_vec(s.rgba).replace(' ', '_')}")
            sub(m, "color", rgba=fmt_vec(s.rgba))


def _origin(parent: ET.Element, X: np.ndarray) -> None:
    sub(parent, "origin", xyz=fmt_vec(X[:3, 3]), rpy=fmt_vec(matrix_to_rpy(X[:3, :3])))
