"""The steps of a plan: consecutive elementary paths of one transition merged into one step
(thesis 000 §3.4.2: "an elementary path belongs to a single transition ... subject to the same
controller from start to end"), and the map from the plan's configuration (robots + objects) to
the configuration of the robot model the controller runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from marionette.planning.path import Plan


class PlanError(ValueError):
    """A plan the execution layer cannot use (unknown robot, layout mismatch, empty plan)."""


@dataclass
class Step:
    """One FSM state: the paths of one (sub-)transition, executed by one controller.

    ``q`` (k x nq_plan) are the plan's samples of the merged paths (joins not repeated) and
    ``path_indices`` the plan paths they come from. Grasps are gripper -> handle maps:
    ``grasps`` hold all along (containing state), ``grasps_from`` / ``grasps_to`` at the ends
    of the sub-transition, ``parent_grasps_from`` / ``parent_grasps_to`` at the ends of the
    whole (waypoint) transition it belongs to.
    """

    index: int
    transition: str
    parent_transition: str
    from_state: str
    to_state: str
    containing_state: str
    grasps: dict[str, str]
    grasps_from: dict[str, str]
    grasps_to: dict[str, str]
    parent_grasps_from: dict[str, str]
    parent_grasps_to: dict[str, str]
    path_indices: list[int]
    q: np.ndarray
    start_state: str | None = None
    end_state: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def released(self) -> dict[str, str]:
        """Grasps opened at the start of this step (release: §3.2.5.1, the gripper opens
        before the robot recedes)."""
        return {g: h for g, h in self.grasps_from.items() if self.grasps_to.get(g) != h}

    @property
    def created(self) -> dict[str, str]:
        """Grasps closed at the end of this step (the gripper reached the handle)."""
        return {g: h for g, h in self.grasps_to.items() if self.grasps_from.get(g) != h}

    @property
    def kind(self) -> str:
        """ "grasp", "release" or "motion" (the three transition types of §3.2.5.1)."""
        if self.created:
            return "grasp"
        if self.released:
            return "release"
        return "motion"

    @property
    def active_grippers(self) -> list[str]:
        """Grippers that hold or approach/leave a handle in this transition (sorted; holders of
        the containing state first)."""
        holders = sorted(self.grasps)
        # Approaching (fig. 3.13 steps 2 and 4: the gripper's pose is controlled from the
        # transit to the pre-grasp on); leaving: only while it still touches the handle at the
        # start of the sub-transition (§3.2.5.1: from the pre-grasp waypoint on, the task of
        # the receding gripper is removed).
        approaching = set(self.parent_grasps_to) - set(self.parent_grasps_from)
        leaving = set(self.parent_grasps_from) - set(self.parent_grasps_to)
        others = (approaching | (leaving & set(self.grasps_from)) | set(self.grasps_to)) - set(
            holders
        )
        return holders + sorted(others)


class PlanRobotMap:
    """Indices of one robot's configuration (its own Pinocchio model, as the controller has it)
    inside the plan's configuration, whose labels are ``<robot>/<joint>`` (free-flyers
    ``<robot>/<joint>.x`` ... ``.qw``; same component order as Pinocchio)."""

    def __init__(self, layout: list[str], model: pin.Model, robot: str) -> None:
        self.model = model
        self.robot = robot
        where = {label: i for i, label in enumerate(layout)}
        idx: list[int] = []
        for jid in range(1, model.njoints):
            joint = model.joints[jid]
            name = f"{robot}/{model.names[jid]}"
            if joint.nq == 1:
                labels = [name]
            elif joint.nq == 7:
                labels = [f"{name}.{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
            else:
                labels = [f"{name}[{i}]" for i in range(joint.nq)]
            missing = [lab for lab in labels if lab not in where]
            if missing:
                raise PlanError(
                    f"the plan has no entry {missing[0]!r} for robot {robot!r} "
                    f"(its layout starts {layout[:3]})"
                )
            idx += [where[lab] for lab in labels]
        self.idx = np.array(idx, dtype=int)
        self.objects: dict[str, np.ndarray] = {}
        for label, i in where.items():
            if label.endswith("/root_joint.x") and not label.startswith(f"{robot}/"):
                self.objects[label.split("/")[0]] = np.arange(i, i + 7)

    def robot_q(self, q_plan: np.ndarray) -> np.ndarray:
        """Robot configuration(s) (..., nq_robot) of plan configuration(s) (..., nq_plan)."""
        return np.asarray(q_plan)[..., self.idx]

    def object_pose(self, q_plan: np.ndarray, name: str) -> pin.SE3:
        """Pose of free object ``name`` in a plan configuration (world frame)."""
        if name not in self.objects:
            raise PlanError(f"no object {name!r} in the plan (objects: {sorted(self.objects)})")
        return pin.XYZQUATToSE3(np.asarray(q_plan)[self.objects[name]])


def plan_robot(plan: Plan) -> str:
    """The (single) robot of a plan: the prefix of its first configuration label."""
    layout = plan.doc["problem"]["configuration_layout"]
    if not layout:
        raise PlanError("the plan has an empty configuration layout")
    return layout[0].split("/")[0]


def steps_from_plan(plan: Plan) -> list[Step]:
    """Merge consecutive paths of the same transition into steps; paths without motion that do
    not change the grasps are dropped first (they carry no motion and no event)."""
    doc = plan.doc
    if not doc["paths"]:
        raise PlanError("the plan has no path")
    states = {s["name"]: dict(s["grasps"]) for s in doc["graph"]["states"]}
    transitions = {t["name"]: t for t in doc["graph"]["transitions"]}
    steps: list[Step] = []
    for entry, (_, qs) in zip(doc["paths"], plan.paths):
        if entry["length"] < 1e-4 and states[entry["from_state"]] == states[entry["to_state"]]:
            continue  # no motion and no grasp change: nothing to execute
        same = steps and steps[-1].transition == entry["transition"]
        if same:
            prev = steps[-1]
            prev.q = np.vstack([prev.q, qs[1:]])
            prev.path_indices.append(entry["index"])
            prev.end_state = entry["end_state"]
            continue
        parent = transitions.get(entry["parent_transition"])
        if parent is None:
            raise PlanError(
                f"path {entry['index']}: unknown transition {entry['parent_transition']!r}"
            )
        step = Step(
            index=len(steps),
            transition=entry["transition"],
            parent_transition=entry["parent_transition"],
            from_state=entry["from_state"],
            to_state=entry["to_state"],
            containing_state=entry["containing_state"],
            grasps=dict(entry["grasps"]),
            grasps_from=states[entry["from_state"]],
            grasps_to=states[entry["to_state"]],
            parent_grasps_from=states[parent["from"]],
            parent_grasps_to=states[parent["to"]],
            path_indices=[entry["index"]],
            q=np.array(qs, dtype=float),
            start_state=entry["start_state"],
            end_state=entry["end_state"],
        )
        steps.append(step)
    return steps
