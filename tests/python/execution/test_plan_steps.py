"""Steps from a plan: a grasp whose approach the planner folded into the transit before it gets
its approach step back (the transit's last path), the samples executed are the plan's, in
order, none lost or repeated; a release's retreat and a plan that has its approach are left as
they are."""

from __future__ import annotations

import numpy as np
import pytest

from marionette.execution.factory import approached_handle
from marionette.execution.plan_steps import steps_from_plan
from marionette.planning.path import Plan

G, H = "robot/gripper", "box/handle"
GRASP = f"{G} > {H} | f"
RELEASE = f"{G} < {H} | 0-f"


def _graph() -> dict:
    held = f"{G} grasps {H}"
    states = [
        {"name": "free", "grasps": {}},
        {"name": f"{GRASP}_pregrasp", "grasps": {}},
        {"name": f"{GRASP}_intersec", "grasps": {G: H}},
        {"name": held, "grasps": {G: H}},
        {"name": f"{RELEASE}_intersec", "grasps": {G: H}},
        {"name": f"{RELEASE}_pregrasp", "grasps": {}},
    ]

    def t(name, frm, to, containing, waypoints=()):
        return {
            "name": name,
            "from": frm,
            "to": to,
            "containing_state": containing,
            "waypoint_edges": list(waypoints),
        }

    transitions = [
        t("Loop | f", "free", "free", "free"),
        t(f"{GRASP}_01", "free", f"{GRASP}_pregrasp", "free"),
        t(f"{GRASP}_12", f"{GRASP}_pregrasp", f"{GRASP}_intersec", "free"),
        t(f"{GRASP}_23", f"{GRASP}_intersec", held, held),
        t(GRASP, "free", held, "free", [f"{GRASP}_01", f"{GRASP}_12", f"{GRASP}_23"]),
        t(f"{RELEASE}_12", held, f"{RELEASE}_pregrasp", held),
        t(f"{RELEASE}_23", f"{RELEASE}_pregrasp", "free", "free"),
        t(RELEASE, held, "free", held, [f"{RELEASE}_12", f"{RELEASE}_23"]),
    ]
    return {"states": states, "transitions": transitions}


def _plan(paths: list[tuple[str, str, str, str, int]]) -> Plan:
    """paths: (transition, parent, from, to, samples); each path's samples continue the last."""
    graph = _graph()
    containing = {t["name"]: t["containing_state"] for t in graph["transitions"]}
    grasps = {s["name"]: s["grasps"] for s in graph["states"]}
    entries, arrays, x = [], [], 0.0
    for i, (name, parent, frm, to, n) in enumerate(paths):
        q = np.array([[x + k, 0.0] for k in range(n)])
        x += n - 1
        entries.append(
            {
                "index": i,
                "transition": name,
                "parent_transition": parent,
                "from_state": frm,
                "to_state": to,
                "containing_state": containing[name],
                "start_state": frm,
                "end_state": to,
                "grasps": grasps[containing[name]],
                "length": float(n - 1),
            }
        )
        arrays.append((np.linspace(0, 1, n), q))
    return Plan({"paths": entries, "graph": graph}, arrays)


def _samples(steps) -> np.ndarray:
    return np.concatenate([steps[0].q[:, 0]] + [s.q[1:, 0] for s in steps[1:]])


PRE, INTER = f"{GRASP}_pregrasp", f"{GRASP}_intersec"


@pytest.mark.parametrize("transit_paths", [1, 3])
def test_a_folded_approach_gets_its_step_back(transit_paths):
    loops = [("Loop | f", "Loop | f", "free", "free", 4)] * transit_paths
    plan = _plan(
        [
            *loops,
            (f"{GRASP}_12", GRASP, PRE, INTER, 3),
            (f"{GRASP}_23", GRASP, INTER, f"{G} grasps {H}", 3),
        ]
    )
    steps = steps_from_plan(plan)
    names = [s.transition for s in steps]
    expected = ["Loop | f"] * (transit_paths > 1) + [f"{GRASP}_01", f"{GRASP}_12", f"{GRASP}_23"]
    assert names == expected
    assert [s.index for s in steps] == list(range(len(steps)))
    approach = steps[names.index(f"{GRASP}_01")]
    assert approach.path_indices == [transit_paths - 1]
    assert approached_handle(approach, G) == H
    assert np.array_equal(_samples(steps), np.arange(len(_samples(steps))))  # all, in order


def test_an_approach_without_motion_is_restored_too():
    plan = _plan(
        [
            ("Loop | f", "Loop | f", "free", "free", 4),
            ("Loop | f", "Loop | f", "free", "free", 4),
            (f"{GRASP}_01", GRASP, "free", PRE, 1),  # length 0: dropped
            (f"{GRASP}_12", GRASP, PRE, INTER, 3),
        ]
    )
    names = [s.transition for s in steps_from_plan(plan)]
    assert names == ["Loop | f", f"{GRASP}_01", f"{GRASP}_12"]


def test_a_plan_with_its_approach_and_a_release_retreat_are_left_alone():
    held = f"{G} grasps {H}"
    plan = _plan(
        [
            ("Loop | f", "Loop | f", "free", "free", 4),
            (f"{GRASP}_01", GRASP, "free", PRE, 3),
            (f"{GRASP}_12", GRASP, PRE, INTER, 3),
            (f"{GRASP}_23", GRASP, INTER, held, 3),
            (f"{RELEASE}_12", RELEASE, held, f"{RELEASE}_pregrasp", 3),
            (f"{RELEASE}_23", RELEASE, f"{RELEASE}_pregrasp", "free", 3),
        ]
    )
    steps = steps_from_plan(plan)
    assert [s.transition for s in steps] == [p["transition"] for p in plan.doc["paths"]]


def test_a_transit_before_a_release_retreat_is_not_an_approach():
    plan = _plan(
        [
            ("Loop | f", "Loop | f", "free", "free", 4),
            (f"{RELEASE}_23", RELEASE, f"{RELEASE}_pregrasp", "free", 3),
        ]
    )
    assert [s.transition for s in steps_from_plan(plan)] == ["Loop | f", f"{RELEASE}_23"]
