"""A problem written for HPP 9 (``bench/hpp_side.py`` builds it in pyhpp): the peer of the
planning benchmarks.

:func:`hpp_description` turns a loaded :class:`ManipulationProblem` into plain JSON: each model's
URDF text and an HPP SRDF made of the grippers, handles, contact surfaces and disabled pairs the
problem read (whatever their source: SRDF, ``grippers.yaml``, inline), the joint bounds, the
graph factory's settings (grippers, objects, environment contacts, rules, weights), the graph
constraints (fixed frames, centre of mass, locked joints, with the values marionette took at
``init``), and the query (legs of a guided plan included).  Same models in the same order as
marionette's, so HPP's configuration vector has marionette's layout, entry for entry.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from marionette.planning.problem import ManipulationProblem, ModelSource


def _pose_attrs(M: pin.SE3) -> dict[str, str]:
    q = pin.Quaternion(M.rotation)
    return {
        "xyz": " ".join(f"{v:.12g}" for v in M.translation),
        "wxyz": f"{q.w:.12g} {q.x:.12g} {q.y:.12g} {q.z:.12g}",
    }


def srdf_text(source: ModelSource) -> str:
    """HPP SRDF of one model: its gripper, handle, contact and disable_collisions elements."""
    root = ET.Element("robot", name=source.name)
    for name, link, M, clearance in source.grippers:
        g = ET.SubElement(root, "gripper", name=name, clearance=f"{clearance:.12g}")
        ET.SubElement(g, "position", _pose_attrs(M))
        ET.SubElement(g, "link", name=link)
    for name, link, M, clearance, mask, approach in source.handles:
        h = ET.SubElement(root, "handle", name=name, clearance=f"{clearance:.12g}")
        ET.SubElement(h, "position", _pose_attrs(M))
        ET.SubElement(h, "link", name=link)
        ET.SubElement(h, "mask").text = " ".join("1" if m else "0" for m in mask)
        ET.SubElement(h, "approaching_direction", xyz=" ".join(f"{v:.12g}" for v in approach))
    for name, link, points in source.contacts:
        c = ET.SubElement(root, "contact", name=name)
        ET.SubElement(c, "link", name=link)
        pts = np.asarray(points, dtype=float)
        ET.SubElement(c, "point").text = " ".join(f"{v:.12g}" for v in pts.ravel())
        ET.SubElement(c, "shape").text = " ".join(str(i) for i in [len(pts), *range(len(pts))])
    for a, b in source.disabled:
        ET.SubElement(root, "disable_collisions", link1=a, link2=b, reason="marionette")
    return ET.tostring(root, encoding="unicode")


def urdf_text(path: Path) -> str:
    """The URDF with relative mesh paths made absolute (``package://`` left to HPP)."""
    tree = ET.parse(path)
    for el in tree.getroot().iter("mesh"):
        fn = el.attrib.get("filename", "")
        if fn and not fn.startswith("package://") and not Path(fn).is_absolute():
            el.attrib["filename"] = str((path.parent / fn).resolve())
    return ET.tostring(tree.getroot(), encoding="unicode")


def _joint_bounds(problem: ManipulationProblem) -> dict[str, list[float]]:
    model = problem.model
    out = {}
    for j in range(1, model.njoints):
        i, n = model.idx_qs[j], model.joints[j].nq
        out[model.names[j]] = [
            float(v) for k in range(i, i + n) for v in (problem.lower[k], problem.upper[k])
        ]
    return out


def _graph_constraints(problem: ManipulationProblem) -> list[dict[str, Any]]:
    """The graph constraints of the problem file with marionette's values (taken at init); the
    centre of mass gives its mask only, HPP's centre of mass being another function."""
    from marionette.planning.constraints import Kinematics

    out: list[dict[str, Any]] = []
    entries = problem.settings.get("constraints", []) or []
    if not entries:
        return out
    q_init = problem.require_init()
    kin = Kinematics(problem.model)
    kin.update(q_init, jacobians=False)
    model = problem.model
    for e in entries:
        if "fixed_frame" in e:
            fid = problem.frame_id(e["fixed_frame"])
            f = model.frames[fid]
            X = kin.data.oMi[f.parentJoint] * f.placement
            out.append(
                {
                    "type": "fixed_frame",
                    "joint": model.names[f.parentJoint],
                    "M_JF": pin.SE3ToXYZQUAT(f.placement).tolist(),
                    "X_WF": pin.SE3ToXYZQUAT(X).tolist(),
                    "mask": [bool(v) for v in e.get("mask", [1] * 6)],
                }
            )
        elif "com" in e:
            out.append(
                {
                    "type": "com",  # its value is HPP's own at init (bench/hpp_side.py)
                    "mask": [bool(v) for v in e["com"]],
                }
            )
        elif "locked_joint" in e:
            jid = model.getJointId(e["locked_joint"])
            i, n = model.idx_qs[jid], model.joints[jid].nq
            out.append(
                {
                    "type": "locked_joint",
                    "joint": e["locked_joint"],
                    "value": q_init[i : i + n].tolist(),
                }
            )
    return out


def arm_indices(problem: ManipulationProblem) -> list[int]:
    """q indices of the robots' 1-dof joints (what "arm path length" sums over)."""
    model = problem.model
    return [
        int(model.idx_qs[j])
        for j in problem.robot_joint_ids
        if model.joints[j].nq == 1 and model.joints[j].nv == 1
    ]


def hpp_description(
    problem: ManipulationProblem,
    legs: list[tuple[np.ndarray, np.ndarray]] | None = None,
) -> dict[str, Any]:
    """Everything bench/hpp_side.py needs to pose ``problem`` in HPP (see the module docstring).
    ``legs``: (start, goal) pairs planned one after the other (a guided problem); default the
    problem's init -> goal."""
    s = problem.settings
    objs = s.get("objects") or {
        o: {"handles": list(i.handles), "contacts": list(i.contacts)}
        for o, i in problem.objects.items()
    }
    if legs is None:
        legs = [(problem.require_init(), problem.require_goal())]
    guide = s.get("guide") or []
    return {
        "name": problem.name,
        "models": [
            {
                "name": m.name,
                "root": "freeflyer" if m.root == "freeflyer" else "anchor",
                "urdf": urdf_text(m.urdf),
                "srdf": srdf_text(m),
                "pose": pin.SE3ToXYZQUAT(m.pose).tolist(),
                "object": m.name in problem.objects,
            }
            for m in problem.models
        ],
        "nq": problem.nq,
        "configuration_layout": problem.configuration_layout(),
        "joint_bounds": _joint_bounds(problem),
        "graph": {
            "grippers": list(s.get("grippers", list(problem.grippers))),
            "objects": [
                [o, list(v.get("handles", [])), list(v.get("contacts", []))]
                for o, v in objs.items()
            ],
            "environment_contacts": list(problem.environment_contacts),
            "rules": [
                [list(r["grippers"]), list(r["handles"]), bool(r.get("link", False))]
                for r in s.get("rules", []) or []
            ],
            "weights": {k: float(v) for k, v in (s.get("weights", {}) or {}).items()},
            "error_threshold": float(s.get("error_threshold", 1e-4)),
            "max_iterations": int(s.get("max_iterations", 40)),
            "preplacement_distance": float(s.get("preplacement_distance", 0.05)),
            "constraints": _graph_constraints(problem),
        },
        "legs": [[np.asarray(a).tolist(), np.asarray(b).tolist()] for a, b in legs],
        # the graph state of each intermediate leg end (a guided problem's waypoints)
        "waypoint_states": [e["state"] for e in guide] if len(legs) == len(guide) + 1 else [],
        "arm_q_indices": arm_indices(problem),
    }
