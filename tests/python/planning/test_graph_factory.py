"""Graph factory: HPP's graph for the UR5 box, the 17-state plank graph of thesis §3.4.2."""

from __future__ import annotations

import itertools

import pytest

import marionette
from marionette.planning.graph import GraphError, LevelSetEdge, WaypointEdge
from marionette.planning.graph_factory import GraphFactory, GraspRules, Rule, graph_from_settings
from marionette.planning.problem import load_problem

TALOS_PLANK = marionette.REPO_ROOT / "tests" / "data" / "planning" / "talos_plank" / "problem.yaml"

# HPP 9.0.2's ConstraintGraphFactory on the same UR5 box problem (the "graph" section of
# bench/ur5_box/problem.yaml, as bench/hpp_side.py poses it to HPP).
HPP_UR5_STATES = {
    "free",
    "ur5/gripper > box/handle | f_intersec",
    "ur5/gripper > box/handle | f_pregrasp",
    "ur5/gripper > box/handle | f_preplace",
    "ur5/gripper grasps box/handle",
}
HPP_UR5_TRANSITIONS = {
    "Loop | 0-0",
    "Loop | f",
    "ur5/gripper < box/handle | 0-0",
    "ur5/gripper < box/handle | 0-0_10",
    "ur5/gripper < box/handle | 0-0_21",
    "ur5/gripper < box/handle | 0-0_32",
    "ur5/gripper < box/handle | 0-0_43",
    "ur5/gripper > box/handle | f",
    "ur5/gripper > box/handle | f_01",
    "ur5/gripper > box/handle | f_12",
    "ur5/gripper > box/handle | f_23",
    "ur5/gripper > box/handle | f_34",
}


def test_ur5_box_graph_is_hpps(ur5_box):
    g = graph_from_settings(ur5_box)
    assert set(g.states) == HPP_UR5_STATES
    # HPP's transitions, plus level-set twins: HPP makes them only between two foliated states;
    # marionette also for one object (graph_factory), each the twin of a transition of HPP's.
    level_sets = {n for n, e in g.edges.items() if isinstance(e, LevelSetEdge)}
    assert set(g.edges) - level_sets == HPP_UR5_TRANSITIONS
    assert level_sets == {"ur5/gripper < box/handle | 0-0_ls"}
    assert all(n.removesuffix("_ls") in HPP_UR5_TRANSITIONS for n in level_sets)
    grasp = g.edges["ur5/gripper > box/handle | f"]
    assert isinstance(grasp, WaypointEdge)
    assert [s.name.split("_")[-1] for s in grasp.waypoints] == ["pregrasp", "intersec", "preplace"]
    # Approach sub-edges lie in 'free' (box stays on the table), the others in the grasp state.
    assert [e.containing.name for e in grasp.sub_edges] == [
        "free",
        "free",
        "ur5/gripper grasps box/handle",
        "ur5/gripper grasps box/handle",
    ]
    assert g.edges["Loop | f"].weight == 0.0 and grasp.weight > 0.0


@pytest.fixture(scope="module")
def plank_graph():
    return graph_from_settings(load_problem(TALOS_PLANK))


def test_plank_graph_has_the_17_states_of_section_3_4_2(plank_graph):
    """5 + 3 + 3 + 3 + 3 states: no gripper on the same side as the other (H1/H2, H3/H4)."""
    H = ["H1", "H2", "H3", "H4"]
    same_side = {frozenset(("H1", "H2")), frozenset(("H3", "H4"))}
    expected = set()
    for h1, h2 in itertools.product(H + [None], repeat=2):
        if h1 is not None and h1 == h2:
            continue
        if h1 and h2 and frozenset((h1, h2)) in same_side:
            continue
        parts = [
            f"talos/{g} grasps plank/{h}"
            for g, h in (("left_gripper", h1), ("right_gripper", h2))
            if h
        ]
        expected.add(" : ".join(parts) or "free")
    assert len(expected) == 17
    assert {s.name for s in plank_graph.main_states()} == expected


def test_plank_graph_transitions(plank_graph):
    g = plank_graph
    main = g.main_states()
    loops = [e for e in g.top_edges() if e.from_state is e.to_state]
    assert len(loops) == 17 and all(e.weight == 0 for e in loops)
    real = [e for e in g.top_edges() if not isinstance(e, LevelSetEdge)]
    grasps = [e for e in real if " > " in e.name]
    releases = [e for e in real if " < " in e.name]
    # Level-set twins (graph_factory): each named after, and moving like, a real transition.
    for e in g.top_edges():
        if isinstance(e, LevelSetEdge):
            twin = g.edges[e.name.removesuffix("_ls")]
            assert (e.from_state, e.to_state) == (twin.from_state, twin.to_state)
    # 8 one-grasp states reached from free, 8 two-grasp states each reached from 2 one-grasp
    # states: 24 grasp transitions, each with its release.
    assert len(grasps) == 24 and len(releases) == 24
    for e in grasps:
        assert len(e.to_state.grasps) == len(e.from_state.grasps) + 1
        assert e.reverse_edge in releases
    # Grasping the plank from the table: pre-grasp, intersection, pre-placement waypoints;
    # taking it with the second hand (plank already held): pre-grasp only.
    first = g.edges["talos/left_gripper > plank/H1 | f"]
    second = g.edges["talos/right_gripper > plank/H3 | 0-0"]
    assert len(first.waypoints) == 3 and len(second.waypoints) == 1
    assert (
        "talos/left_gripper grasps plank/H1 : talos/right_gripper grasps plank/H3"
        == second.to_state.name
    )
    # No transition into a pruned state.
    names = {s.name for s in main}
    assert all(e.to_state.name in names for e in grasps + releases)


def test_rules_are_hpps_first_match_semantics():
    rules = GraspRules(
        ["g1", "g2"],
        ["H1", "H2"],
        [Rule(["g1", "g2"], ["H1", "H2"], False), Rule([".*"], [".*"], True)],
    )
    assert rules((None, None))
    assert rules((0, None))
    assert not rules((0, 1))
    assert rules((1, 0))
    assert not GraspRules(["g1"], ["H1"], [Rule(["g1"], ["H1"], True)])(
        (None,)
    )  # no match: refused


def test_factory_rejects_unknown_names(ur5_box):
    with pytest.raises(GraphError, match="unknown gripper"):
        GraphFactory(ur5_box, ["ur5/nope"], {"box": ["box/handle"]})
    with pytest.raises(GraphError, match="unknown handle"):
        GraphFactory(ur5_box, ["ur5/gripper"], {"box": ["box/nope"]})


def test_graph_picture_is_written(ur5_box, tmp_path):
    g = graph_from_settings(ur5_box)
    png = g.write_picture(tmp_path / "graph.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    dot = g.to_dot()
    assert dot.count("->") == len(g.edges) - sum(
        isinstance(e, WaypointEdge) for e in g.edges.values()
    )


def test_transition_weights_from_the_problem_file(ur5_box):
    ur5_box.settings["weights"] = {"ur5/gripper > box/handle | f": 3.0}
    try:
        g = graph_from_settings(ur5_box)
        assert g.edges["ur5/gripper > box/handle | f"].weight == 3.0
        ur5_box.settings["weights"] = {"nope": 1.0}
        with pytest.raises(GraphError, match="no top-level transition"):
            graph_from_settings(ur5_box)
    finally:
        del ur5_box.settings["weights"]
