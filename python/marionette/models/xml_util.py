"""Small helpers to write URDF/MJCF deterministically: number formatting, rotations, indenting."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping

import numpy as np


def fmt(x: float) -> str:
    """A number with 12 significant digits, shortest form, no negative zero ('0.1', '-1e-05')."""
    v = float(f"{float(x):.12g}")
    if v == 0.0:
        return "0"
    if v == int(v) and abs(v) < 1e15:
        return str(int(v))
    return repr(v)


def fmt_vec(v: Iterable[float]) -> str:
    return " ".join(fmt(a) for a in v)


def rpy_to_matrix(rpy: Iterable[float]) -> np.ndarray:
    """URDF roll-pitch-yaw (fixed axes x, y, z): R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix, with w >= 0 (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * np.sqrt(1.0 + t)
        c = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        c = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        c = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        c = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(c)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def quat_wxyz_to_matrix(q: Iterable[float]) -> np.ndarray:
    w, x, y, z = np.asarray(list(q), dtype=float) / np.linalg.norm(list(q))
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def homogeneous(R: np.ndarray | None = None, p: Iterable[float] | None = None) -> np.ndarray:
    X = np.eye(4)
    if R is not None:
        X[:3, :3] = R
    if p is not None:
        X[:3, 3] = list(p)
    return X


def matrix_to_rpy(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rpy_to_matrix` (pitch in [-pi/2, pi/2])."""
    pitch = np.arcsin(-np.clip(R[2, 0], -1.0, 1.0))
    if abs(np.cos(pitch)) > 1e-9:
        roll = np.arctan2(R[2, 1], R[2, 2])
        yaw = np.arctan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: put everything in yaw
        roll = 0.0
        yaw = np.arctan2(-R[0, 1], R[1, 1])
    return np.array([roll, pitch, yaw])


def indent_and_serialize(root: ET.Element, header_comment: str | None = None) -> str:
    """Pretty XML text (two-space indent, trailing newline), optionally after a comment."""
    ET.indent(root, space="  ")
    body = ET.tostring(root, encoding="unicode")
    out = '<?xml version="1.0" encoding="utf-8"?>\n'
    if header_comment:
        out += f"<!-- {header_comment} -->\n"
    return out + body + "\n"


def sub(
    parent: ET.Element,
    tag: str,
    attrib: Mapping[str, str | None] | None = None,
    **attrs: str | None,
) -> ET.Element:
    """ET.SubElement with attributes in the given order (``attrib`` first, for names that are
    Python keywords such as ``class``), skipping None values."""
    merged = {**(attrib or {}), **attrs}
    return ET.SubElement(parent, tag, {k: v for k, v in merged.items() if v is not None})


def attribute(e: ET.Element, name: str, where: str, error: type[Exception] = ValueError) -> str:
    """Attribute ``name`` of ``e``; raises ``error`` naming ``where`` and the element when the
    file lacks it."""
    value = e.get(name)
    if value is None:
        raise error(f"{where}: <{e.tag}> has no {name!r} attribute")
    return value


def child(e: ET.Element, tag: str, where: str, error: type[Exception] = ValueError) -> ET.Element:
    """The first ``<tag>`` child of ``e``; raises ``error`` naming ``where`` when there is none."""
    found = e.find(tag)
    if found is None:
        raise error(f"{where}: <{e.tag}> has no <{tag}> element")
    return found


def numbers(
    text: str, where: str, count: int | None = None, error: type[Exception] = ValueError
) -> tuple[float, ...]:
    """The whitespace-separated numbers of an attribute's ``text`` (exactly ``count`` of them
    when given); raises ``error`` naming ``where`` and the text otherwise."""
    try:
        values = tuple(float(a) for a in text.split())
    except ValueError:
        raise error(f"{where}: {text!r} is not a list of numbers") from None
    if count is not None and len(values) != count:
        raise error(f"{where}: {text!r} has {len(values)} numbers, expected {count}")
    return values
