"""The C++ path validator (marionette._core.planning) against the Python one and brute force.

The C++ validator re-implements ``CollisionChecker._certified`` for speed; it must give the same
verdicts and the same collision-free prefixes on the paths a planner actually checks (transit,
grasp approach with the box held, polylines of projected humanoid paths), and never accept a path
that dense sampling finds in collision.
"""

from __future__ import annotations

import numpy as np
import pytest

import marionette
from marionette.planning import collision_cpp
from marionette.planning.collision import CollisionChecker
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.planner import ManipulationRRT
from marionette.planning.problem import load_problem, random_configuration

TALOS_PLANK = (
    marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems" / "talos_plank.yaml"
)


def _recorded_paths(problem, seeds):
    """Every (path, allowed, prefix) a Manipulation-RRT validates on the given seeds."""
    graph = graph_from_settings(problem)
    graph.initialize()
    checker = CollisionChecker(problem, backend="python")
    calls = []
    validate = checker.validate

    def record(path, allowed=None, prefix=True):
        calls.append((path, allowed, prefix))
        return validate(path, allowed, prefix)

    checker.validate = record
    for s in seeds:
        # Extensions toward uniform samples only (HPP's): long straight paths, many of them in
        # collision, so that both verdicts are exercised.
        assert (
            ManipulationRRT(problem, graph, checker, seed=s, local_rate=0.0)
            .solve(problem.q_init, [problem.q_goal], 2000, 60)
            .success
        )
    return calls


def _first_dense_collision(checker, path, allowed, step=2e-3):
    """Arc length of the first colliding sample every ``step`` (Python, configuration checks)."""
    for s in np.linspace(0.0, path.length, int(np.ceil(path.length / step)) + 1):
        if not checker.is_valid(path.eval(s), allowed):
            return s
    return None


@pytest.fixture(scope="module")
def ur5_paths(ur5_box):
    return _recorded_paths(ur5_box, [1, 2, 3])


def test_same_verdicts_and_prefixes_as_python_on_planner_paths(ur5_box, ur5_paths):
    py = CollisionChecker(ur5_box, backend="python")
    cpp = CollisionChecker(ur5_box, backend="cpp")
    kinds = set()
    for path, allowed, prefix in ur5_paths:
        a = py.validate(path, allowed, prefix)
        b = cpp.validate(path, allowed, prefix)
        assert a[0] == b[0], path.edge.name
        assert b[1] == pytest.approx(a[1], abs=1e-9), path.edge.name
        kinds.add((path.edge.name, a[0], prefix))
    # Both verdicts, both modes, transit and transfer (box held) transitions were exercised.
    assert {ok for _, ok, _ in kinds} == {True, False}
    assert {pre for _, _, pre in kinds} == {True, False}
    assert len({name for name, _, _ in kinds}) >= 4
    assert cpp.checks == py.checks  # the same certified steps, query for query


def test_never_accepts_what_dense_sampling_finds_in_collision(ur5_box, ur5_paths):
    cpp = CollisionChecker(ur5_box, backend="cpp")
    rng = np.random.default_rng(3)
    picked = [
        ur5_paths[i]
        for i in rng.choice(len(ur5_paths), size=min(40, len(ur5_paths)), replace=False)
    ]
    for path, allowed, prefix in picked:
        if allowed is None:
            allowed = cpp.grasp_contact_pairs(path.edge.grasps)
        ok, s_valid = cpp.validate(path, allowed, prefix)
        brute = _first_dense_collision(cpp, path, allowed)
        if ok:
            assert brute is None, path.edge.name
        elif brute is not None:
            assert brute >= s_valid - 1e-9  # the certified prefix is collision-free


def test_pair_speed_bounds_match_python(ur5_box):
    checker = CollisionChecker(ur5_box, backend="cpp")
    graph = graph_from_settings(ur5_box)
    rng = np.random.default_rng(0)
    for edge in (graph.edges["Loop | f"], graph.edges["Loop | 0-0"]):
        rigid, R, L, _ = checker._motion(edge.path_projector)
        skip = np.zeros(len(checker.pairs), dtype=bool)
        motion = collision_cpp._planning.PairMotion(rigid, skip, R, L)
        for _ in range(5):
            qa, qb = random_configuration(ur5_box, rng), random_configuration(ur5_box, rng)
            ang, lin = checker._joint_speeds(qa, qb)
            expected = np.where(rigid, 0.0, R @ ang + L @ lin)
            np.testing.assert_allclose(
                checker._cpp.pair_speeds(qa, qb, motion), expected, rtol=1e-12, atol=1e-15
            )


def test_projected_humanoid_polylines_agree_with_python():
    """TALOS paths with feet and CoM constraints are polylines of projections: the C++ side
    walks their vertices and substitutes the locked plank exactly as Python does."""
    problem = load_problem(TALOS_PLANK)
    graph = graph_from_settings(problem)
    py = CollisionChecker(problem, backend="python")
    cpp = CollisionChecker(problem, backend="cpp")
    state = graph.state_of(problem.q_init)
    edge = next(e for e in state.outgoing if e.to_state is state)
    rng = np.random.default_rng(2)
    checked = multi = 0
    for _ in range(30):
        q = random_configuration(problem, rng)
        if not edge.generate_target(problem.q_init, q):
            continue
        paths = edge.build(problem.q_init, q)
        if not paths:
            continue
        for path in paths:
            multi += len(path.points) > 2
            a, b = py.validate(path), cpp.validate(path)
            # Same verdict; the prefix may differ in the 7th decimal: the pair speed bounds are
            # sums taken in another order (BLAS vs Eigen), and near a contact the certified steps
            # d / u are tiny, so ulp-level differences shift where the contact is met.
            assert a[0] == b[0]
            assert b[1] == pytest.approx(a[1], abs=1e-6)
            checked += 1
        if checked >= 4 and multi >= 2:
            break
    assert checked >= 4 and multi >= 2


def test_bad_input_is_a_precise_error(ur5_box):
    checker = CollisionChecker(ur5_box, backend="cpp")
    v = checker._cpp
    n = len(checker.pairs)
    motion = collision_cpp._planning.PairMotion(
        np.zeros(n, bool),
        np.zeros(n, bool),
        np.zeros((n, ur5_box.model.njoints)),
        np.zeros((n, ur5_box.model.njoints)),
    )
    sub = collision_cpp._planning.Substitution([], [], [], [], [])
    with pytest.raises(ValueError, match="nq"):
        v.validate(np.zeros((2, 3)), np.array([0.0, 1.0]), sub, motion, False)
    with pytest.raises(ValueError, match="npairs"):
        bad = collision_cpp._planning.PairMotion(
            np.zeros(2, bool), np.zeros(2, bool), np.zeros((2, 2)), np.zeros((2, 2))
        )
        v.validate(np.tile(ur5_box.q_init, (2, 1)), np.array([0.0, 1.0]), sub, bad, False)
    with pytest.raises(ValueError, match="backend"):
        CollisionChecker(ur5_box, backend="fortran")
    with pytest.raises(ValueError, match="kind 'Planar'"):
        collision_cpp._planning.PathValidator(
            [collision_cpp._planning.JointSpec("j", 0, "Planar", np.zeros(3), np.eye(4))],
            [],
            [],
            1e-6,
            10,
        )


def _two_spheres(kind: str, lever: float):
    """Sphere A (radius 0.1) on joint 1 (``kind``), ``lever`` along x from its axis; sphere B
    (radius 0.2) fixed in the world."""
    P = collision_cpp._planning
    joints = [P.JointSpec("a", 0, kind, np.zeros(3), np.eye(4))]
    XA = np.eye(4)
    XA[0, 3] = lever
    return P, joints, XA


@pytest.mark.parametrize("kind", ["PX", "RZ"])
def test_stops_at_the_closed_form_first_contact(kind):
    """A sphere driven towards another: the certified prefix ends at the analytic contact
    (never after it, within CONTACT-sized steps of it); a path ending before it is accepted."""
    from marionette.planning.collision import CONTACT, MAX_QUERIES

    if kind == "PX":
        P, joints, XA = _two_spheres(kind, 0.0)
        XB = np.eye(4)
        XB[0, 3] = 1.0
        s_contact = 1.0 - 0.3  # centres 0.3 apart
        R, L = [[0.0, 0.1]], [[0.0, 1.0]]  # translation: |dq| per unit t
        q_end = 2.0
    else:
        P, joints, XA = _two_spheres(kind, 1.0)
        theta_b = 2.0
        XB = np.eye(4)
        XB[:2, 3] = [np.cos(theta_b), np.sin(theta_b)]
        # Centres on the unit circle: chord 2 sin(dtheta / 2) = 0.3 at first contact.
        s_contact = theta_b - 2.0 * np.arcsin(0.15)
        R, L = [[0.0, 1.1]], [[0.0, 0.0]]  # a point of A is at most 1.1 from the axis
        q_end = np.pi
    geoms = [
        P.GeometrySpec("A", 1, XA, "sphere", radius=0.1),
        P.GeometrySpec("B", 0, XB, "sphere", radius=0.2),
    ]
    v = P.PathValidator(joints, geoms, [(0, 1)], CONTACT, MAX_QUERIES)
    motion = P.PairMotion(np.zeros(1, bool), np.zeros(1, bool), np.array(R), np.array(L))
    sub = P.Substitution([], [], [], [], [])
    ok, s_valid, queries, grazing = v.validate(
        np.array([[0.0], [q_end]]), np.array([0.0, q_end]), sub, motion, False
    )
    assert not ok and not grazing
    assert s_contact - 1e-4 <= s_valid <= s_contact
    assert v.distances(np.array([s_valid]))[0] == pytest.approx(0.0, abs=2e-4)
    short = 0.95 * s_contact
    ok, s_valid, _, _ = v.validate(
        np.array([[0.0], [short]]), np.array([0.0, short]), sub, motion, False
    )
    assert ok and s_valid == short
    # All or nothing: the probe at half the length already sees the spheres overlap.
    ok, s_valid, queries, _ = v.validate(
        np.array([[0.0], [2 * s_contact + 0.05]]),
        np.array([0.0, 2 * s_contact + 0.05]),
        sub,
        motion,
        True,
    )
    assert not ok and s_valid == 0.0 and queries == 0


def test_a_clearance_stops_at_the_closed_form_distance_and_is_excused_at_a_close_end():
    """Sphere A driven along x towards sphere B (centres 1 apart, radii 0.1 + 0.2): with a
    clearance of 0.05 the certified prefix ends where the surfaces are 0.05 apart (s = 0.65), not
    at contact (s = 0.7); a path starting 0.02 from B (closer than the clearance: a given start)
    may move on that pair down to contact; is_clear tells the clearance at a configuration."""
    from marionette.planning.collision import CONTACT, MAX_QUERIES

    P, joints, XA = _two_spheres("PX", 0.0)
    XB = np.eye(4)
    XB[0, 3] = 1.0
    geoms = [
        P.GeometrySpec("A", 1, XA, "sphere", radius=0.1),
        P.GeometrySpec("B", 0, XB, "sphere", radius=0.2),
    ]
    v = P.PathValidator(joints, geoms, [(0, 1)], CONTACT, MAX_QUERIES)
    clearance = 0.05
    motion = P.PairMotion(
        np.zeros(1, bool),
        np.zeros(1, bool),
        np.array([[0.0, 0.1]]),
        np.array([[0.0, 1.0]]),
        np.array([clearance]),
    )
    sub = P.Substitution([], [], [], [], [])

    def validate(q0: float, q1: float):
        return v.validate(np.array([[q0], [q1]]), np.array([0.0, abs(q1 - q0)]), sub, motion, False)

    ok, s_valid, _, grazing = validate(0.0, 2.0)
    assert not ok and not grazing
    assert 0.65 - 1e-4 <= s_valid <= 0.65  # distance 1 - 0.3 - s = clearance
    assert validate(0.0, 0.64)[0]
    # An end closer than the clearance excuses the pair on that path (a planner creates no such
    # end: is_clear below), so 0.66 is accepted where 2.0 was stopped at 0.65.
    assert validate(0.0, 0.66)[0]
    # From 0.02 away (a given start): excused on this pair, stopped at contact only.
    ok, s_valid, _, _ = validate(0.68, 0.0)
    assert ok
    ok, s_valid, _, _ = validate(0.68, 2.0)
    assert not ok and s_valid == pytest.approx(0.02, abs=1e-4)
    assert v.is_clear(np.array([0.64]), motion) and not v.is_clear(np.array([0.66]), motion)
    # Without a clearance: contact only, as before.
    plain = P.PairMotion(np.zeros(1, bool), np.zeros(1, bool), motion.R, motion.L)
    assert v.validate(np.array([[0.0], [0.69]]), np.array([0.0, 0.69]), sub, plain, False)[0]
    assert v.is_clear(np.array([0.69]), plain)
