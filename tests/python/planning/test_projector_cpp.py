"""The C++ projector (backend="cpp") against the Python reference (backend="python").

Both run the same Newton loop (Algorithm 1 with the same schedule, limits, priorities, bounds
and failure reasons), so from the same start they take the same steps: converged
configurations agree to 1e-9 and failures give the same reason.  The C++ Jacobians are checked
against finite differences of the C++ errors, as the Python ones are in test_constraints.py.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import marionette
from marionette.planning.constraints import (
    ComPosition,
    Constraint,
    LockedJoint,
    Placement,
    Transformation,
)
from marionette.planning.graph import WaypointEdge
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.problem import load_problem, random_configuration
from marionette.planning.projector import ALGORITHM_1, LineSearch, ProjectionStatus, Projector
from planning.test_constraints import constraints_under_test

PROBLEMS = marionette.REPO_ROOT / "python" / "marionette" / "planning" / "problems"


def python_twin(proj: Projector, constraints=None, **overrides) -> Projector:
    """The reference projector with the same constraints and settings as ``proj``."""
    kw = dict(
        error_threshold=proj.error_threshold,
        max_iterations=proj.max_iterations,
        line_search=proj.line_search,
        damping=proj.damping,
    )
    kw.update(overrides)
    return Projector(
        proj.problem,
        proj.constraints if constraints is None else constraints,
        backend="python",
        **kw,
    )


def every_projector(graph):
    """(label, projector) of every state and of every transition's path and target."""
    for name, s in graph.states.items():
        yield f"state {name}", s.projector
    for e in graph.edges.values():
        edges = e.sub_edges if isinstance(e, WaypointEdge) else [e]
        for sub in edges:
            yield f"path {sub.name}", sub.path_projector
            yield f"target {sub.name}", sub.target_projector


def outcome(model, r_a, q_a, r_b, q_b) -> str:
    """ "success" (both converged, in as many iterations, 1e-9 apart), "success 1e-6" (the
    same, 1e-6 apart), "same failure" (same reason after as many iterations), "disagree"."""
    if (r_a.status, r_a.iterations) != (r_b.status, r_b.iterations):
        return "disagree"
    if not r_a.success:
        return "same failure"
    d = np.abs(pin.difference(model, q_a, q_b)).max()
    return "success" if d < 1e-9 else "success 1e-6" if d < 1e-6 else "disagree"


def compare(
    problem, cpp: Projector, py: Projector, rng, starts: int, rhs_configs, tweak=None
) -> dict:
    """Project the same starts with both backends and count the outcomes (:func:`outcome`);
    at every start, the first Newton step of both must agree: within 1e-6 always (same logic
    everywhere: a different formula would be off by the step itself), within 1e-10 but at
    rare ill-conditioned starts (counted as "first step 1e-6", :func:`assert_agree`).
    ``tweak(q0)`` edits the starts in place."""
    model = problem.model
    counts = {
        "success": 0,
        "success 1e-6": 0,
        "same failure": 0,
        "disagree": 0,
        "first step 1e-6": 0,
    }
    for k in range(starts):
        q_rhs = rhs_configs[k % len(rhs_configs)]
        py.set_rhs_from(q_rhs)
        cpp.set_rhs_from(q_rhs)
        q0 = random_configuration(problem, rng)
        if tweak is not None:
            tweak(q0)
        q_c, q_p = q0.copy(), q0.copy()
        r_p = py.project(q_p)
        r_c = cpp.project(q_c)
        if r_c.success:
            assert cpp.is_satisfied(q_c), f"start {k}: C++ reports success off the constraints"
        counts[outcome(model, r_p, q_p, r_c, q_c)] += 1
        its = py.max_iterations, cpp.max_iterations
        py.max_iterations = cpp.max_iterations = 1
        q_c, q_p = q0.copy(), q0.copy()
        py.project(q_p)
        cpp.project(q_c)
        py.max_iterations, cpp.max_iterations = its
        step_apart = np.abs(pin.difference(model, q_p, q_c)).max()
        assert step_apart < 1e-6, f"start {k}: first steps {step_apart:.1e} apart"
        counts["first step 1e-6"] += int(step_apart >= 1e-10)
    return counts


def add(total: dict, counts: dict) -> None:
    for k, v in counts.items():
        total[k] = total.get(k, 0) + v


def assert_agree(total: dict, fraction: float = 0.02) -> None:
    """Disagreements, successes more than 1e-9 apart and first steps more than 1e-10 apart stay
    rare.  They are runs through
    ill-conditioned iterates (far from the manifold, joints saturated and their columns
    removed: the damped Gram matrix J J^T + 1e-8 I has a condition number near 1e8) where
    the ulp-level differences of BLAS vs Eigen sums grow, iteration after iteration (traced:
    1e-16, 1e-14, 1e-11, 1e-8, ...), until they change where or whether the run ends.
    Algorithm 1's short steps and the 44-dof humanoid spend more iterations there than the
    default schedule on the UR arms."""
    n = sum(v for k, v in total.items() if k != "first step 1e-6")  # one outcome per start
    assert total["disagree"] <= fraction * n, total
    assert total["success 1e-6"] <= fraction * n, total
    assert total["first step 1e-6"] <= fraction * n, total


@pytest.mark.parametrize("problem_file", ["ur5_box", "ur10_box"])
def test_same_results_as_python_on_every_state_and_transition(ur5_box, problem_file):
    problem = ur5_box if problem_file == "ur5_box" else load_problem(PROBLEMS / "ur10_box.yaml")
    graph = graph_from_settings(problem)
    rng = np.random.default_rng(11)
    # Right-hand sides from the start, the goal and configurations of the grasp state.
    rhs_configs = [problem.q_init, problem.q_goal]
    grasp = next(s for s in graph.states.values() if s.grasps and not s.waypoint)
    while len(rhs_configs) < 5:
        q = random_configuration(problem, rng)
        if grasp.project(q):
            rhs_configs.append(q)
    total: dict = {}
    for label, proj in every_projector(graph):
        assert proj.backend == "cpp", f"{label}: {proj.fallback_reason}"
        add(total, compare(problem, proj, python_twin(proj), rng, 12, rhs_configs))
    # Both outcomes were exercised, many times.
    assert total["success"] >= 300 and total["same failure"] >= 50, total
    assert_agree(total)


@pytest.mark.parametrize(
    "line_search",
    [ALGORITHM_1, LineSearch("error_norm", max_step=0.5)],
    ids=["algorithm_1", "error_norm"],
)
def test_same_results_with_the_other_step_size_schedules(ur5_box, line_search):
    graph = graph_from_settings(ur5_box)
    rng = np.random.default_rng(5)
    total: dict = {}
    for name in ("free", "ur5/gripper > box/handle | f_pregrasp"):
        base = graph.states[name].projector
        cpp = Projector(
            ur5_box,
            base.constraints,
            error_threshold=base.error_threshold,
            max_iterations=base.max_iterations,
            line_search=line_search,
        )
        add(total, compare(ur5_box, cpp, python_twin(cpp), rng, 100, [ur5_box.q_init]))
    assert total["success"] >= 20, total
    assert_agree(total, 0.1)


def test_same_results_with_priority_levels(ur5_box):
    """Gripper position first, a wrist target second (3 dof left for it): the null-space steps
    agree."""
    p = ur5_box
    g = p.grippers["ur5/gripper"]
    position = Transformation(
        "position",
        g.joint_id,
        p.model.frames[g.frame_id].placement,
        pin.SE3(np.eye(3), np.array([0.4, 0.1, 0.3])),
        mask=(True, True, True, False, False, False),
    )
    wrist = LockedJoint("wrist", p.model, p.model.getJointId("ur5/wrist_1_joint"), np.array([0.3]))
    levels = dict(levels=[0, 1], max_iterations=30)
    cpp = Projector(ur5_box, [position, wrist.as_implicit()], **levels)
    py = python_twin(cpp, **levels)
    total = compare(ur5_box, cpp, py, np.random.default_rng(9), 60, [ur5_box.q_init])
    assert total["success"] >= 10, total
    assert_agree(total, 0.1)


def test_same_saturation_at_joint_bounds(ur5_box):
    """A pan target beyond its range: both end on the bound (saturated column removed), the
    other joint converged, after the same iterations and with the same failure reason."""
    p = ur5_box
    model = p.model
    pan = LockedJoint("pan", model, model.getJointId("ur5/shoulder_pan_joint"), np.array([4.0]))
    elbow = LockedJoint("elbow", model, model.getJointId("ur5/elbow_joint"), np.array([0.3]))
    cpp = Projector(p, [pan.as_implicit(), elbow.as_implicit()], max_iterations=20)
    py = python_twin(cpp)
    rng = np.random.default_rng(2)
    for _ in range(10):
        q0 = random_configuration(p, rng)
        q_c, q_p = q0.copy(), q0.copy()
        r_c, r_p = cpp.project(q_c), py.project(q_p)
        assert (r_c.status, r_c.iterations) == (r_p.status, r_p.iterations)
        assert not r_c.success and q_c[0] == p.upper[0]
        assert q_c[2] == pytest.approx(0.3, abs=1e-6)
        np.testing.assert_allclose(q_c, q_p, atol=1e-12)


def test_talos_plank_states_agree_with_python():
    """TALOS (free-flyer root, two-hand grasps turned implicit, feet fixed, centre of mass over
    them, locked joints): every state in C++, with the same outcomes as the Python reference,
    from perturbations of the start (uniform samples of 44 dof are too far to converge)."""
    problem = load_problem(PROBLEMS / "talos_plank.yaml")
    graph = graph_from_settings(problem)
    rng = np.random.default_rng(4)
    checked = 0
    total: dict = {}

    def near_start(q0):
        q0[:] = pin.integrate(problem.model, problem.q_init, 0.1 * rng.standard_normal(problem.nv))

    for _name, s in graph.states.items():
        cpp = s.projector
        assert cpp.backend == "cpp", cpp.fallback_reason
        assert any(isinstance(c, ComPosition) for c in cpp.implicit)
        add(
            total,
            compare(problem, cpp, python_twin(cpp), rng, 3, [problem.q_init], tweak=near_start),
        )
        checked += 1
    assert checked == len(graph.states)
    assert total["success"] >= 10, total
    assert_agree(total, 0.1)


@pytest.fixture(scope="module")
def talos_plank():
    return load_problem(PROBLEMS / "talos_plank.yaml")


@pytest.mark.parametrize("frame", ["world", "left_sole"])
@pytest.mark.parametrize("mask", [(True, True, False), (True, True, True), (False, True, True)])
def test_cpp_com_matches_python_and_finite_differences(talos_plank, frame, mask):
    """The C++ centre-of-mass constraint (the whole model's CoM -- robot and plank -- in a
    frame: the world, or a foot frame on the moving leg chain) against the Python reference
    ``ComPosition`` (value and Jacobian, 1e-12) and against central finite differences of its
    own error, at random whole-body configurations."""
    p = talos_plank
    if frame == "world":
        joint, M = 0, pin.SE3.Identity()
    else:
        f = p.model.frames[p.frame_id("talos/left_sole_link")]
        joint, M = f.parentJoint, f.placement
    com = ComPosition("com", joint, M, target=np.array([0.01, -0.02, 0.8]), mask=mask)
    proj = Projector(p, [com])
    assert proj.backend == "cpp", proj.fallback_reason
    py = python_twin(proj)
    cpp = proj._cpp
    rng = np.random.default_rng(11)
    for _ in range(4):
        q = random_configuration(p, rng)
        rhs, pairs = cpp.rhs(), cpp.pairs()
        e = cpp.cpp.error(q, rhs, pairs)
        np.testing.assert_allclose(e, py.error(q), atol=1e-12)
        J = cpp.cpp.jacobian(q, rhs, pairs)
        py.kin.update(q)
        np.testing.assert_allclose(J, com.compute_jacobian(py.kin), atol=1e-12)
        J_fd = np.zeros_like(J)
        for i in range(p.nv):
            dv = np.zeros(p.nv)
            dv[i] = 1e-6
            ep = cpp.cpp.error(pin.integrate(p.model, q, dv), rhs, pairs)
            em = cpp.cpp.error(pin.integrate(p.model, q, -dv), rhs, pairs)
            J_fd[:, i] = (ep - em) / 2e-6
        np.testing.assert_allclose(J, J_fd, atol=2e-7, rtol=1e-5)


def test_cpp_com_projection_balances_the_humanoid(talos_plank):
    """Projected onto feet fixed + CoM over them, from perturbed postures: the result satisfies
    both by an independent measure (Pinocchio's centerOfMass and frame placements), and the
    same start gives the Python reference's configuration."""
    p = talos_plank
    graph = graph_from_settings(p)
    proj = graph.states["free"].projector
    assert proj.backend == "cpp"
    py = python_twin(proj)
    data = p.model.createData()
    pin.framesForwardKinematics(p.model, data, p.q_init)
    feet = ["talos/left_sole_link", "talos/right_sole_link"]
    X0 = [data.oMf[p.frame_id(f)].copy() for f in feet]
    c0 = pin.centerOfMass(p.model, data, p.q_init).copy()
    rng = np.random.default_rng(5)
    converged = 0
    for _ in range(8):
        q = pin.integrate(p.model, p.q_init, 0.15 * rng.standard_normal(p.nv))
        q_py = q.copy()
        proj.set_rhs_from(p.q_init)
        py.set_rhs_from(p.q_init)
        r = proj.project(q)
        r_py = py.project(q_py)
        assert r.status is r_py.status
        if not r:
            continue
        converged += 1
        assert np.abs(pin.difference(p.model, q, q_py)).max() < 1e-6
        pin.framesForwardKinematics(p.model, data, q)
        for f, X in zip(feet, X0):
            assert np.linalg.norm(pin.log6(X.actInv(data.oMf[p.frame_id(f)])).vector) < 2e-4
        c = pin.centerOfMass(p.model, data, q)
        assert np.linalg.norm(c[:2] - c0[:2]) < 2e-4
    assert converged >= 4


@pytest.mark.parametrize(
    "which",
    [
        "relative_transformation_6d",
        "relative_transformation_mask",
        "transformation",
        "placement",
        "placement_complement",
        "grasp_as_implicit",
        "locked_freeflyer_as_implicit",
        "locked_revolute_as_implicit",
    ],
)
def test_cpp_errors_match_python_and_jacobians_match_finite_differences(ur5_box, which):
    p = ur5_box
    c = constraints_under_test(p)[which]
    plc = c if isinstance(c, Placement) else getattr(c, "placement", None)
    constraints = [c] if plc is None or plc is c else [plc, c]
    proj = Projector(p, constraints, levels=[0] * len(constraints))
    assert proj.backend == "cpp"
    cpp = proj._cpp
    rows = slice(proj.size - c.size, proj.size)  # c is the last constraint
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = random_configuration(p, rng)
        rhs, pairs = cpp.rhs(), cpp.pairs()
        e = cpp.cpp.error(q, rhs, pairs)[rows]
        np.testing.assert_allclose(e, proj.error(q)[rows], atol=1e-12, err_msg=which)
        J = cpp.cpp.jacobian(q, rhs, pairs)[rows]
        J_fd = np.zeros_like(J)
        for i in range(p.nv):
            dv = np.zeros(p.nv)
            dv[i] = 1e-6
            ep = cpp.cpp.error(pin.integrate(p.model, q, dv), rhs, pairs)[rows]
            em = cpp.cpp.error(pin.integrate(p.model, q, -dv), rhs, pairs)[rows]
            J_fd[:, i] = (ep - em) / 2e-6
        np.testing.assert_allclose(J, J_fd, atol=2e-6, rtol=1e-5, err_msg=which)


class _Height(Constraint):
    """A constraint kind the C++ projector does not know: the z of joint 6's origin."""

    def __init__(self):
        super().__init__("height of joint 6", 1)

    def value(self, kin):
        return kin.oMi[6].translation[2:3]

    def compute_jacobian(self, kin):
        J = pin.getJointJacobian(kin.model, kin.data, 6, pin.LOCAL_WORLD_ALIGNED)
        return J[2:3]


def test_projector_with_an_unknown_kind_falls_back_to_python_once(ur5_box):
    proj = Projector(ur5_box, [_Height()])
    assert proj.backend == "python"
    assert "_Height" in proj.fallback_reason and "no C++ implementation" in proj.fallback_reason
    q = ur5_box.q_init.copy()
    proj.set_rhs_from(q)
    q2 = random_configuration(ur5_box, np.random.default_rng(0))
    assert proj.project(q2).status in set(ProjectionStatus)


def test_bad_input_is_a_precise_error(ur5_box):
    with pytest.raises(ValueError, match="backend must be 'cpp' or 'python'"):
        Projector(ur5_box, [], backend="fortran")
    proj = Projector(ur5_box, [constraints_under_test(ur5_box)["transformation"]])
    cpp = proj._cpp.cpp
    q = ur5_box.q_init.copy()
    with pytest.raises(ValueError, match="rhs has 2 entries, expected 6"):
        cpp.project(q, np.zeros(2), [], 1e-4, 10)
    with pytest.raises(ValueError, match="q has 3 entries"):
        cpp.project(np.zeros(3), np.zeros(6), [], 1e-4, 10)
    with pytest.raises(ValueError, match="max_iterations"):
        cpp.project(q, np.zeros(6), [], 1e-4, 0)
    # A q the projector cannot write in place (not float64) is copied and written back.
    q32 = ur5_box.q_init.astype(np.float32)
    r = proj.project(q32)
    q64 = ur5_box.q_init.copy()
    assert proj.project(q64).status is r.status


@pytest.mark.parametrize("problem_file", ["ur5_box", "ur10_box"])
def test_membership_verdicts_match_python(ur5_box, problem_file):
    """State.contains / Edge.can_connect (is_satisfied): the same verdict as the reference on
    configurations of each state, on them moved by 1e-5 to 1e-3 (across the 1e-4 threshold)
    and on uniform samples; the surface pair chosen is the same."""
    problem = ur5_box if problem_file == "ur5_box" else load_problem(PROBLEMS / "ur10_box.yaml")
    graph = graph_from_settings(problem)
    model = problem.model
    rng = np.random.default_rng(8)
    verdicts = {True: 0, False: 0}
    for label, proj in every_projector(graph):
        py = python_twin(proj)
        for k in range(8):
            q_rhs = problem.q_init if k % 2 else problem.q_goal
            proj.set_rhs_from(q_rhs)
            py.set_rhs_from(q_rhs)
            q = random_configuration(problem, rng)
            candidates = [q.copy()]
            if proj.project(q):
                candidates += [q] + [
                    pin.integrate(model, q, s * rng.standard_normal(model.nv))
                    for s in (1e-5, 1e-4, 1e-3)
                ]
            for c in candidates:
                expected = py.is_satisfied(c)
                pairs_py = [p.pair for p in proj._cpp.placements]
                assert proj.is_satisfied(c) == expected, label
                assert [p.pair for p in proj._cpp.placements] == pairs_py, label
                verdicts[expected] += 1
    assert verdicts[True] >= 100 and verdicts[False] >= 100, verdicts
