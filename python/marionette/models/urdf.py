"""A URDF reader (kinematics, inertia, geometry) and its translation to an MJCF body tree.

We translate URDF ourselves rather than through MuJoCo's importer + ``mj_saveLastXML``: the saved
file rounds every number to 6 significant digits, which breaks the 1e-6 agreement with
Pinocchio that tests/cpp/sim/mjcf_model_test.cc checks, and it orders sibling bodies by file
order while Pinocchio orders them by its own traversal. Here bodies follow Pinocchio's order, so
MuJoCo's joint order equals Pinocchio's, and numbers keep 12 significant digits.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .xml_util import (
    attribute,
    child,
    fmt,
    fmt_vec,
    homogeneous,
    matrix_to_quat_wxyz,
    numbers,
    rpy_to_matrix,
    sub,
)


class UrdfError(ValueError):
    """The URDF uses something this translator does not support; the message says what."""


MOVABLE = ("revolute", "continuous", "prismatic")


@dataclass
class Geometry:
    kind: str  # "box" | "cylinder" | "sphere" | "mesh"
    X_LG: np.ndarray  # (4, 4) geometry frame in the link frame
    size: tuple[float, ...] = ()  # box: full extents; cylinder: (radius, length); sphere: (r,)
    filename: str = ""
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    rgba: tuple[float, float, float, float] | None = None
    name: str | None = None


@dataclass
class Inertial:
    mass: float
    X_LI: np.ndarray  # (4, 4) inertial frame in the link frame
    inertia: np.ndarray  # (3, 3) about the CoM, in the inertial frame


@dataclass
class Link:
    name: str
    inertial: Inertial | None = None
    collisions: list[Geometry] = field(default_factory=list)
    visuals: list[Geometry] = field(default_factory=list)


@dataclass
class Joint:
    name: str
    type: str
    parent: str
    child: str
    X_PJ: np.ndarray  # (4, 4) joint (= child link) frame in the parent link frame
    axis: np.ndarray  # (3,) unit, in the joint frame
    lower: float | None = None
    upper: float | None = None
    effort: float | None = None
    velocity: float | None = None
    damping: float = 0.0
    friction: float = 0.0
    mimic: Mimic | None = None  # <mimic>: this joint's value follows another joint's


@dataclass(frozen=True)
class Mimic:
    """URDF ``<mimic joint multiplier offset>``: q = multiplier * q_joint + offset."""

    joint: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass
class Urdf:
    name: str
    links: dict[str, Link]
    joints: dict[str, Joint]  # in file order
    text: str

    @property
    def root(self) -> str:
        children = {j.child for j in self.joints.values()}
        roots = [name for name in self.links if name not in children]
        if len(roots) != 1:
            raise UrdfError(f"{self.name}: expected one root link, found {roots}")
        return roots[0]

    def child_joints(self, link: str) -> list[Joint]:
        return [j for j in self.joints.values() if j.parent == link]

    def parent_joint(self, link: str) -> Joint | None:
        for j in self.joints.values():
            if j.child == link:
                return j
        return None

    def subtree(self, link: str) -> list[str]:
        """``link`` and every link below it."""
        out = [link]
        for j in self.child_joints(link):
            out += self.subtree(j.child)
        return out


def parse_urdf(text: str) -> Urdf:
    """Parse URDF text (no xacro); raises UrdfError naming the element that lacks a required
    attribute or child."""
    root = ET.fromstring(text)
    if root.tag != "robot":
        raise UrdfError(f"not a URDF: root element is <{root.tag}>")
    robot_name = attribute(root, "name", "URDF", UrdfError)
    materials: dict[str, tuple[float, float, float, float]] = {}
    for m in root.findall("material"):
        c = m.find("color")
        if c is not None:
            name = attribute(m, "name", robot_name, UrdfError)
            materials[name] = _rgba(c, f"{robot_name}: material {name}")
    links: dict[str, Link] = {}
    for le in root.findall("link"):
        link = Link(attribute(le, "name", robot_name, UrdfError))
        where = f"{robot_name}: link {link.name}"
        ie = le.find("inertial")
        if ie is not None:
            inertia = child(ie, "inertia", where, UrdfError)
            ixx, iyy, izz, ixy, ixz, iyz = (
                float(inertia.get(k, "0")) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")
            )
            mass = attribute(child(ie, "mass", where, UrdfError), "value", where, UrdfError)
            link.inertial = Inertial(
                mass=float(mass),
                X_LI=_origin(ie, where),
                inertia=np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]),
            )
        for tag, out in (("collision", link.collisions), ("visual", link.visuals)):
            for ge in le.findall(tag):
                g = _geometry(ge, materials, where)
                if g is not None:
                    out.append(g)
        links[link.name] = link
    joints: dict[str, Joint] = {}
    for je in root.findall("joint"):
        name = attribute(je, "name", robot_name, UrdfError)
        where = f"{robot_name}: joint {name}"
        kind = attribute(je, "type", where, UrdfError)
        axis_e = je.find("axis")
        axis = (
            np.array(numbers(axis_e.get("xyz", "1 0 0"), f"{where}: axis", 3, UrdfError))
            if axis_e is not None
            else np.array([1.0, 0.0, 0.0])
        )
        if kind in MOVABLE:
            if np.linalg.norm(axis) < 1e-12:
                raise UrdfError(f"{where}: zero axis")
            axis = axis / np.linalg.norm(axis)
        j = Joint(
            name=name,
            type=kind,
            parent=attribute(child(je, "parent", where, UrdfError), "link", where, UrdfError),
            child=attribute(child(je, "child", where, UrdfError), "link", where, UrdfError),
            X_PJ=_origin(je, where),
            axis=axis,
        )
        lim = je.find("limit")
        if lim is not None:
            j.lower = _opt(lim.get("lower"))
            j.upper = _opt(lim.get("upper"))
            j.effort = _opt(lim.get("effort"))
            j.velocity = _opt(lim.get("velocity"))
        dyn = je.find("dynamics")
        if dyn is not None:
            j.damping = float(dyn.get("damping", "0"))
            j.friction = float(dyn.get("friction", "0"))
        mimic = je.find("mimic")
        if mimic is not None:
            j.mimic = Mimic(
                attribute(mimic, "joint", where, UrdfError),
                float(mimic.get("multiplier", "1")),
                float(mimic.get("offset", "0")),
            )
        joints[j.name] = j
    return Urdf(robot_name, links, joints, text)


def pinocchio_link_order(urdf: Urdf) -> list[str]:
    """Links in the order Pinocchio's URDF parser visits them (its frame order)."""
    import pinocchio as pin

    model = pin.buildModelFromXML(urdf.text)
    order = [f.name for f in model.frames if f.type == pin.FrameType.BODY]
    missing = set(urdf.links) - set(order)
    if missing:
        raise UrdfError(f"{urdf.name}: Pinocchio has no body frame for links {sorted(missing)}")
    return order


@dataclass
class MjcfTree:
    """An MJCF body tree made from a URDF, plus what the caller needs to complete the model."""

    root: ET.Element  # the root link's <body>
    meshes: dict[str, tuple[str, tuple[float, float, float]]]  # asset name -> (file, scale)
    joints: list[Joint]  # movable joints, in MJCF (= Pinocchio) order
    bodies: dict[str, ET.Element]  # link name -> its <body>
    # Joints that follow another one (URDF <mimic>), made hinges or slides in MJCF and tied to
    # their joint by an equality (:func:`mimic_equality`); Pinocchio keeps them fixed, so they
    # are not in ``joints`` (no actuator, not in the controller's configuration).
    mimics: list[Joint] = field(default_factory=list)


def urdf_to_mjcf(
    urdf: Urdf,
    mesh_file: Callable[[str], str],
    mesh_prefix: str,
    geom_class: Callable[[str], str],
    armature: Callable[[Joint], float] = lambda j: 0.0,
    visuals: bool = False,
    mimics: bool = False,
    collision_meshes: Callable[[str, str], list[str]] | None = None,
) -> MjcfTree:
    """Translate ``urdf`` into a body tree rooted at its root link (placed at the origin).

    ``mesh_file`` maps a URDF mesh URI to the MJCF mesh file (relative to ``meshdir``);
    ``mesh_prefix`` prefixes mesh asset names (unique in a scene); ``geom_class(link)`` names
    the default class of the link's collision geoms. Collision geoms are also what MuJoCo
    renders; with ``visuals``, visual elements that differ from every collision element are
    added in class "visual". A DAE collision mesh (MuJoCo 2.2 reads STL/OBJ/MSH only) is
    replaced by the link's first STL visual mesh when it has one (else ``mesh_file`` must convert
    it). A root link named ``world`` (a URDF that fixes its base to the world) is MuJoCo's
    reserved world body: its body is named ``<robot>_world`` instead. With ``mimics``, a joint that
    carries a
    ``<mimic>`` of a movable joint becomes an unactuated MJCF joint (listed in ``tree.mimics``)
    even when the URDF fixes it (a reduced humanoid URDF may fix its grippers' fingers).
    ``collision_meshes(link, uri)``, when given, names the MJCF mesh files that stand for a
    collision mesh (one geom each: a concave mesh's convex pieces); default ``[mesh_file(uri)]``.
    """
    order = {name: i for i, name in enumerate(pinocchio_link_order(urdf))}
    tree = MjcfTree(root=ET.Element("body"), meshes={}, joints=[], bodies={})

    def add_link(body: ET.Element, link_name: str) -> None:
        link = urdf.links[link_name]
        tree.bodies[link_name] = body
        if link.inertial is not None and link.inertial.mass > 0:
            _add_inertial(body, link.inertial)
        joint = urdf.parent_joint(link_name)
        driver = _mimic_driver(urdf, joint) if mimics and joint is not None else None
        if joint is not None and driver is not None:
            # A mimic moves as its driver does (a slide for a prismatic driver), whatever type
            # the URDF gives it (fixed, for Pinocchio).
            _add_joint(body, joint, armature(joint), mimic=driver.type)
            tree.mimics.append(joint)
        elif joint is not None and joint.type in MOVABLE:
            _add_joint(body, joint, armature(joint))
            tree.joints.append(joint)
        elif joint is not None and joint.type != "fixed":
            raise UrdfError(f"{urdf.name}: joint {joint.name} of type {joint.type} not supported")
        for g in _collision_geometries(link):
            files = None
            if g.kind == "mesh" and collision_meshes is not None:
                files = collision_meshes(link_name, g.filename)
            _add_geom(body, g, geom_class(link_name), mesh_file, mesh_prefix, tree.meshes, files)
        if visuals:
            for g in link.visuals:
                if not any(_same_geometry(g, c) for c in link.collisions):
                    _add_geom(body, g, "visual", mesh_file, mesh_prefix, tree.meshes)
        for j in sorted(urdf.child_joints(link_name), key=lambda j: order[j.child]):
            child = sub(body, "body", name=j.child)
            _set_pose(child, j.X_PJ)
            add_link(child, j.child)

    tree.root.set("name", f"{urdf.name}_world" if urdf.root == "world" else urdf.root)
    add_link(tree.root, urdf.root)
    return tree


def _mimic_driver(urdf: Urdf, joint: Joint) -> Joint | None:
    """The joint ``joint`` mimics (None: it is not a mimic); raises UrdfError when that driver
    is not a movable joint or is itself a mimic."""
    if joint.mimic is None:
        return None
    driver = urdf.joints.get(joint.mimic.joint)
    if driver is None or driver.type not in MOVABLE:
        raise UrdfError(
            f"{urdf.name}: joint {joint.name} mimics {joint.mimic.joint}, "
            "which is not a movable joint"
        )
    if driver.mimic is not None:
        raise UrdfError(f"{urdf.name}: joint {joint.name} mimics {driver.name}, itself a mimic")
    return driver


def mimic_equality(joint: Joint) -> ET.Element:
    """MuJoCo 2.2 ``<equality><joint>`` for a URDF mimic: q1 - q1_0 = a0 + a1 (q2 - q2_0) with
    q1 the mimic joint, q2 its driver (both with qpos0 = 0: the URDF's zero); a0 = offset,
    a1 = multiplier. Stiffer than MuJoCo's default (time constant 5 ms instead of 20 ms, critically
    damped), so a finger pressed by a contact lags its driver by little."""
    m = joint.mimic
    if m is None:
        raise UrdfError(f"joint {joint.name} has no <mimic>: it follows no joint")
    return ET.Element(
        "joint",
        name=f"{joint.name}_mimic",
        joint1=joint.name,
        joint2=m.joint,
        polycoef=fmt_vec([m.offset, m.multiplier, 0, 0, 0]),
        solref="0.005 1",
    )


def _collision_geometries(link: Link) -> list[Geometry]:
    out = []
    for g in link.collisions:
        if g.kind == "mesh" and g.filename.lower().endswith(".dae"):
            stl = [
                v for v in link.visuals if v.kind == "mesh" and v.filename.lower().endswith(".stl")
            ]
            if stl:
                if stl[0] not in out:
                    out.append(stl[0])
                continue
        out.append(g)  # a DAE with no STL twin: the mesh namer converts it
    return out


def _same_geometry(a: Geometry, b: Geometry) -> bool:
    return (
        a.kind == b.kind
        and np.allclose(a.X_LG, b.X_LG)
        and a.size == b.size
        and a.filename == b.filename
        and a.scale == b.scale
    )


def _add_inertial(body: ET.Element, inertial: Inertial) -> None:
    R = inertial.X_LI[:3, :3]
    I_L = R @ inertial.inertia @ R.T  # rotational inertia about the CoM, axes of the link frame
    pos = fmt_vec(inertial.X_LI[:3, 3])
    off = I_L - np.diag(np.diag(I_L))
    if np.all(np.abs(off) <= 1e-14 * max(1.0, np.abs(I_L).max())):
        sub(
            body,
            "inertial",
            pos=pos,
            mass=fmt(inertial.mass),
            diaginertia=fmt_vec(np.maximum(np.diag(I_L), 0.0)),
        )
        return
    eig = np.linalg.eigvalsh(I_L)
    if eig.min() > 0:
        sub(
            body,
            "inertial",
            pos=pos,
            mass=fmt(inertial.mass),
            fullinertia=fmt_vec([I_L[0, 0], I_L[1, 1], I_L[2, 2], I_L[0, 1], I_L[0, 2], I_L[1, 2]]),
        )
        return
    # Not positive definite (a few upstream links carry placeholder inertias): keep the
    # principal axes, clamp negative moments to 0 (MuJoCo's boundinertia lifts them).
    w, V = np.linalg.eigh(I_L)
    if np.linalg.det(V) < 0:
        V[:, 0] = -V[:, 0]
    sub(
        body,
        "inertial",
        pos=pos,
        quat=fmt_vec(matrix_to_quat_wxyz(V)),
        mass=fmt(inertial.mass),
        diaginertia=fmt_vec(np.maximum(w, 0.0)),
    )


def _add_joint(body: ET.Element, joint: Joint, armature: float, mimic: str | None = None) -> None:
    """``mimic``: the URDF type of the joint this one follows (None: not a mimic)."""
    kind = "slide" if (mimic or joint.type) == "prismatic" else "hinge"
    # A mimic joint is bounded through its driver: its own limit would only fight the equality.
    limits = None
    if not mimic and joint.type != "continuous":
        if joint.lower is not None and joint.upper is not None:
            limits = fmt_vec([joint.lower, joint.upper])
    # Dry friction as in the URDF, but at most 10 % of the effort limit: a URDF may give a
    # gripper 1 N m of friction for 1 N m of effort, which would lock it.
    friction = joint.friction
    if joint.effort:
        friction = min(friction, 0.1 * joint.effort)
    sub(
        body,
        "joint",
        name=joint.name,
        type=kind,
        axis=fmt_vec(joint.axis),
        range=limits,
        limited="false" if limits is None else "true",
        damping=fmt(joint.damping) if joint.damping else None,
        frictionloss=fmt(friction) if friction else None,
        armature=fmt(armature) if armature else None,
    )


def _add_geom(
    body: ET.Element,
    g: Geometry,
    cls: str,
    mesh_file: Callable[[str], str],
    mesh_prefix: str,
    meshes: dict[str, tuple[str, tuple[float, float, float]]],
    files: list[str] | None = None,
) -> None:
    """A geom for ``g`` in ``body``; a mesh given as several ``files`` gets one geom each."""
    attrs: dict[str, str | None] = {"class": cls}
    if g.name:
        attrs["name"] = g.name
    if g.kind == "mesh":
        files = files or [mesh_file(g.filename)]
        for k, file in enumerate(files):
            stem = file.rsplit(".", 1)[0]
            name = f"{mesh_prefix}{stem}"
            if g.scale != (1.0, 1.0, 1.0):
                name += "_s" + "_".join(fmt(s).replace("-", "m") for s in g.scale)
            meshes[name] = (file, g.scale)
            piece = dict(attrs, type="mesh", mesh=name)
            if g.name and len(files) > 1:
                piece["name"] = f"{g.name}_{k}"
            if g.rgba is not None:
                piece["rgba"] = fmt_vec(g.rgba)
            _set_pose(sub(body, "geom", piece), g.X_LG)
        return
    if g.kind == "box":
        attrs.update(type="box", size=fmt_vec(np.array(g.size) / 2))
    elif g.kind == "cylinder":
        attrs.update(type="cylinder", size=fmt_vec([g.size[0], g.size[1] / 2]))
    elif g.kind == "sphere":
        attrs.update(type="sphere", size=fmt(g.size[0]))
    if g.rgba is not None:
        attrs["rgba"] = fmt_vec(g.rgba)
    geom = sub(body, "geom", attrs)
    _set_pose(geom, g.X_LG)


def _set_pose(el: ET.Element, X: np.ndarray) -> None:
    if np.any(np.abs(X[:3, 3]) > 0):
        el.set("pos", fmt_vec(X[:3, 3]))
    q = matrix_to_quat_wxyz(X[:3, :3])
    if abs(q[0] - 1.0) > 1e-15:
        el.set("quat", fmt_vec(q))


def _origin(e: ET.Element, where: str) -> np.ndarray:
    o = e.find("origin")
    if o is None:
        return np.eye(4)
    xyz = numbers(o.get("xyz", "0 0 0"), f"{where}: origin xyz", 3, UrdfError)
    rpy = numbers(o.get("rpy", "0 0 0"), f"{where}: origin rpy", 3, UrdfError)
    return homogeneous(rpy_to_matrix(rpy), xyz)


def _rgba(color: ET.Element, where: str) -> tuple[float, float, float, float]:
    r, g, b, a = numbers(attribute(color, "rgba", where, UrdfError), where, 4, UrdfError)
    return r, g, b, a


def _geometry(
    ge: ET.Element, materials: dict[str, tuple[float, float, float, float]], where: str
) -> Geometry | None:
    """The shape of a ``<collision>`` or ``<visual>`` of link ``where``, or None when empty."""
    shape = ge.find("geometry")
    if shape is None or len(shape) == 0:
        return None
    s = shape[0]
    where = f"{where}: {ge.tag} <{s.tag}>"
    X = _origin(ge, where)
    rgba = None
    m = ge.find("material")
    if m is not None:
        c = m.find("color")
        rgba = (
            _rgba(c, where)
            if c is not None
            else materials.get(attribute(m, "name", where, UrdfError))
        )
    name = ge.get("name")

    def number(key: str) -> float:
        (value,) = numbers(attribute(s, key, where, UrdfError), f"{where} {key}", 1, UrdfError)
        return value

    if s.tag == "box":
        size = numbers(attribute(s, "size", where, UrdfError), f"{where} size", 3, UrdfError)
        return Geometry("box", X, size, rgba=rgba, name=name)
    if s.tag == "cylinder":
        return Geometry("cylinder", X, (number("radius"), number("length")), rgba=rgba, name=name)
    if s.tag == "sphere":
        return Geometry("sphere", X, (number("radius"),), rgba=rgba, name=name)
    if s.tag == "mesh":
        sx, sy, sz = numbers(s.get("scale", "1 1 1"), f"{where} scale", 3, UrdfError)
        filename = attribute(s, "filename", where, UrdfError)
        return Geometry("mesh", X, filename=filename, scale=(sx, sy, sz), rgba=rgba, name=name)
    raise UrdfError(f"{where}: unsupported geometry")


def _opt(v: str | None) -> float | None:
    return None if v is None else float(v)


def read_urdf(path: str | Path) -> Urdf:
    return parse_urdf(Path(path).read_text())
