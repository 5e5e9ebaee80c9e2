"""The steps of a plan: consecutive elementary paths of one transition merged into one step
(thesis 000 §3.4.2: "an elementary path belongs to a single transition ... subject to the same
controller from start to end"), and the map from the plan's configuration (robots + objects) to
the configuration of the robot model the controller runs.
"""

from __future__ import annotations

import dataclasses
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
    not change the grasps are dropped first (they carry no motion and no event). A grasp whose
    approach the planner folded into the transit before it (no path, or a path without motion,
    of the waypoint transition that reaches the pre-grasp) gets it back: the transit's last path
    becomes the approach step (:func:`_restore_approach`)."""
    doc = plan.doc
    if not doc["paths"]:
        raise PlanError("the plan has no path")
    states = {s["name"]: dict(s["grasps"]) for s in doc["graph"]["states"]}
    transitions = {t["name"]: t for t in doc["graph"]["transitions"]}
    steps: list[Step] = []
    pieces: list[list[tuple[dict, np.ndarray]]] = []  # per step, its paths (entry, samples)
    for entry, (_, path_q) in zip(doc["paths"], plan.paths):
        if entry["length"] < 1e-4 and states[entry["from_state"]] == states[entry["to_state"]]:
            continue  # no motion and no grasp change: nothing to execute
        qs = np.array(path_q, dtype=float)
        same = steps and steps[-1].transition == entry["transition"]
        if same:
            prev = steps[-1]
            prev.q = np.vstack([prev.q, qs[1:]])
            prev.path_indices.append(entry["index"])
            prev.end_state = entry["end_state"]
            pieces[-1].append((entry, qs))
            continue
        steps.append(_step(len(steps), entry, transitions, states, qs))
        pieces.append([(entry, qs)])
    k = 1
    while k < len(steps):
        if _restore_approach(steps, pieces, k, transitions, states):
            k += 1  # the step that came after the transit is now at k + 1
        k += 1
    for i, step in enumerate(steps):
        step.index = i
    return steps


def _step(
    index: int, entry: dict, transitions: dict[str, dict], states: dict[str, dict], q: np.ndarray
) -> Step:
    parent = transitions.get(entry["parent_transition"])
    if parent is None:
        raise PlanError(f"path {entry['index']}: unknown transition {entry['parent_transition']!r}")
    return Step(
        index=index,
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
        q=q,
        start_state=entry["start_state"],
        end_state=entry["end_state"],
    )


def _restore_approach(
    steps: list[Step],
    pieces: list[list[tuple[dict, np.ndarray]]],
    k: int,
    transitions: dict[str, dict],
    states: dict[str, dict],
) -> bool:
    """When ``steps[k]`` leaves a pre-grasp that no step reached (the transit ``steps[k - 1]``
    ended there: the planner's path to the pre-grasp was part of the transit), the transit's
    last path becomes the approach, labelled with the waypoint transition that reaches the
    pre-grasp, so that a gripper task — servoed on the object with vision — drives the hand to
    it as in the plans that have the approach. True when a step was inserted at ``k``."""
    step, transit = steps[k], steps[k - 1]
    if step.from_state.rsplit("_", 1)[-1] != "pregrasp" or transit.to_state == step.from_state:
        return False
    if transit.created or transit.released or transit.grasps != step.grasps:
        return False
    parent = transitions.get(step.parent_transition, {})
    waypoint = next(
        (
            transitions[name]
            for name in parent.get("waypoint_edges", ())
            if name in transitions and transitions[name]["to"] == step.from_state
        ),
        None,
    )
    if waypoint is None or waypoint["from"] != transit.to_state:
        return False
    approached = set(states[parent["to"]]) - set(states[parent["from"]])
    if not approached:  # a release's retreat leaves its pre-grasp: nothing is approached
        return False
    entry, qs = pieces[k - 1][-1]
    approach = _step(
        k,
        {
            **entry,
            "transition": waypoint["name"],
            "parent_transition": step.parent_transition,
            "from_state": waypoint["from"],
            "to_state": waypoint["to"],
            "containing_state": waypoint["containing_state"],
            "grasps": states[waypoint["containing_state"]],
        },
        transitions,
        states,
        qs,
    )
    if len(pieces[k - 1]) > 1:  # the transit keeps its other paths
        pieces[k - 1].pop()
        transit.q = transit.q[: len(transit.q) - (len(qs) - 1)]
        transit.path_indices.pop()
        transit.end_state = pieces[k - 1][-1][0]["end_state"]
        steps.insert(k, approach)
        pieces.insert(k, [(entry, qs)])
        return True
    steps[k - 1] = dataclasses.replace(approach, index=k - 1)  # the whole transit approaches
    return False
