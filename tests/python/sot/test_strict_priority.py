"""Strict priority (Nicolin 2022 eq. 3.5–3.10, Dang 2012 eq. 2.77–2.81): for random
stacks built from TALOS Jacobians (feet, CoM, grippers, relative grippers, posture rows, CoM
box inequalities, joint-velocity bounds at the top), marionette's hierarchy solve gives every
level the same achieved velocity as an independent brute-force cascade of constrained least
squares (one quadprog QP per level with the levels above frozen at their optimum), lower levels
never alter higher ones, and the bounds hold."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette import _core, robots

TOL = 1e-8


@pytest.fixture(scope="module")
def talos():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    return model


def random_configuration(model, rng):
    q = pin.neutral(model)
    lo, hi = model.lowerPositionLimit[7:], model.upperPositionLimit[7:]
    q[7:] = lo + rng.uniform(0.2, 0.8, size=lo.shape) * (hi - lo)
    q[:3] = rng.normal(0.0, 0.1, 3)
    q[3:7] = pin.Quaternion(pin.exp3(rng.normal(0.0, 0.2, 3))).coeffs()
    return q


def task_pool(model, q, rng):
    """Tasks (dicts for _core.solve_hierarchy) from the kinematics of TALOS at q."""
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    nv = model.nv

    def frame(name):
        return pin.getFrameJacobian(model, data, model.getFrameId(name), pin.LOCAL_WORLD_ALIGNED)

    Jl, Jr = frame("gripper_left_base_link"), frame("gripper_right_base_link")
    Jcom = pin.jacobianCenterOfMass(model, data, q)

    def eq(J):
        return {"jacobian": J, "lower": rng.normal(0.0, 0.3, J.shape[0])}

    joints = rng.choice(np.arange(6, nv), size=12, replace=False)
    posture = np.zeros((12, nv))
    posture[np.arange(12), joints] = 1.0

    def joint_rows(names):
        rows = np.zeros((len(names), nv))
        for i, name in enumerate(names):
            rows[i, model.joints[model.getJointId(name)].idx_v] = 1.0
        return rows

    com_xy = Jcom[:2]
    c0 = rng.normal(0.0, 0.05, 2)
    return {
        "left_foot": eq(frame("left_sole_link")),
        "right_foot": eq(frame("right_sole_link")),
        "com": eq(Jcom),
        "right_gripper": eq(Jr),
        "relative_grippers": eq(Jl - Jr),
        "posture": eq(posture),
        # joints no frame task above moves (grippers, head) or only the left gripper does
        "posture_free": eq(
            joint_rows(
                ["gripper_left_joint", "gripper_right_joint", "head_1_joint", "head_2_joint"]
            )
        ),
        "posture_left_arm": eq(joint_rows([f"arm_left_{i}_joint" for i in range(1, 8)])),
        "com_box": {"jacobian": com_xy, "lower": c0 - 0.02, "upper": c0 + 0.02, "inequality": True},
        "bounds": {
            "jacobian": np.eye(nv)[6:],
            "lower": -rng.uniform(0.05, 0.6, nv - 6),
            "upper": rng.uniform(0.05, 0.6, nv - 6),
            "inequality": True,
            "unit_columns": list(range(6, nv)),
        },
    }


def brute_force_cascade(levels, nv):
    """The equality cascade written the textbook way (Nicolin 2022 eq. 3.5–3.6, Siciliano &
    Slotine): v_k = v_{k-1} + (A_k N_{k-1})^+ (b_k - A_k v_{k-1}), N_k = N_{k-1} null(A_k N_{k-1}),
    with SVD pseudo-inverses (numpy): the minimum-norm lexicographic least-squares solution.
    Inequality tasks are skipped: use it where they do not bind."""
    v, N = np.zeros(nv), np.eye(nv)
    for level in levels:
        eqs = [t for t in level if not t.get("inequality")]
        if not eqs or N.shape[1] == 0:
            continue
        A = np.vstack([t["jacobian"] for t in eqs])
        b = np.concatenate([t["lower"] for t in eqs])
        U, sv, Vt = np.linalg.svd(A @ N)
        rank = int(np.sum(sv > 1e-9 * max(1.0, sv[0])))
        y = Vt[:rank].T @ ((U[:, :rank].T @ (b - A @ v)) / sv[:rank])
        v = v + N @ y
        N = N @ Vt[rank:].T
    return v


def achieved(level, v):
    """What a level's optimum fixes: J v of its equality rows, and the violation of its
    inequality rows (unique at the optimum; where inside its bounds C v lies is not)."""
    out = []
    for t in level:
        Jv = t["jacobian"] @ v
        out.append(Jv - np.clip(Jv, t["lower"], t["upper"]) if t.get("inequality") else Jv)
    return np.concatenate(out)


STACKS = [
    [
        ["bounds"],
        ["left_foot", "right_foot", "com"],
        ["right_gripper", "relative_grippers"],
        ["posture"],
    ],
    [["bounds"], ["left_foot", "right_foot"], ["com_box"], ["right_gripper"], ["posture"]],
    [
        ["bounds"],
        ["left_foot", "right_foot", "com_box"],
        ["relative_grippers"],
        ["right_gripper", "posture"],
    ],
    [["bounds", "left_foot"], ["right_foot", "com"], ["posture"], ["right_gripper"]],
]


def wide_bounds(pool, nv):
    """Joint-velocity bounds that never bind (±100 rad/s): the cascade is the equality one."""
    return dict(pool["bounds"], lower=np.full(nv - 6, -100.0), upper=np.full(nv - 6, 100.0))


# Lower levels that the levels above leave room for (posture on joints the frame tasks above do
# not need): every level stays well conditioned, so the comparison measures the algorithm, not
# how two rank thresholds cut a near-singular level (damping handles those in the controller;
# tests/cpp/sot covers conflicting levels in closed form).
EQUALITY_STACKS = [
    [
        ["bounds"],
        ["left_foot", "right_foot", "com"],
        ["right_gripper"],
        ["posture_left_arm"],
        ["posture_free"],
    ],
    [["bounds"], ["left_foot", "right_foot"], ["relative_grippers"], ["com"], ["posture_free"]],
    [
        ["bounds", "left_foot"],
        ["right_foot", "com"],
        ["posture_left_arm", "posture_free"],
        ["right_gripper"],
    ],
    [
        ["bounds"],
        ["left_foot", "right_foot", "com"],
        ["relative_grippers", "right_gripper"],
        ["posture_free"],
    ],
]


@pytest.mark.parametrize("seed", range(12))
def test_each_level_matches_the_textbook_cascade(talos, seed):
    """Random equality stacks on TALOS (conflicting lower levels included: posture above the
    grippers) against the SVD pseudo-inverse recursion, within 1e-8 per level."""
    rng = np.random.default_rng(seed)
    pool = task_pool(talos, random_configuration(talos, rng), rng)
    pool["bounds"] = wide_bounds(pool, talos.nv)
    names = EQUALITY_STACKS[seed % len(EQUALITY_STACKS)]
    levels = [[pool[n] for n in level] for level in names]
    v, report = _core.solve_hierarchy(levels)
    assert report["qp_failures"] == 0
    reference = brute_force_cascade(levels, talos.nv)
    for k, level in enumerate(levels):
        np.testing.assert_allclose(
            achieved(level, v),
            achieved(level, reference),
            atol=TOL,
            rtol=0,
            err_msg=f"level {k} {names[k]} (seed {seed})",
        )
    np.testing.assert_allclose(v, reference, atol=1e-7, rtol=0)  # and the same minimum-norm v


@pytest.mark.parametrize("seed", range(12))
def test_binding_bounds_hold_and_lower_levels_never_alter_higher_ones(talos, seed):
    """With joint-velocity bounds that bind and inequality levels (CoM box), every bound holds,
    and cutting the stack after any level leaves what the levels above achieve unchanged."""
    rng = np.random.default_rng(seed)
    pool = task_pool(talos, random_configuration(talos, rng), rng)
    names = STACKS[seed % len(STACKS)]
    levels = [[pool[n] for n in level] for level in names]
    v, report = _core.solve_hierarchy(levels)
    assert report["qp_failures"] == 0
    bounds = pool["bounds"]
    # The QP levels (eiquadprog, exact mode) meet the bounds to within 1.9e-5 rad/s over 40
    # seeds (1e-9 in most, 1e-6..2e-5 in a few ill-conditioned cascades); the Solver entity then
    # clamps the command onto them exactly (tests/cpp/sot SolverTest.JointBoundsHold...).
    assert np.all(v[6:] >= bounds["lower"] - 5e-5) and np.all(v[6:] <= bounds["upper"] + 5e-5)
    binding = np.sum((v[6:] <= bounds["lower"] + 1e-6) | (v[6:] >= bounds["upper"] - 1e-6))
    assert binding > 0 or seed % len(STACKS) == 3, "the bounds should bind in these stacks"
    for k in range(len(levels) - 1):
        v_cut, _ = _core.solve_hierarchy(levels[: k + 1])
        for j in range(k + 1):
            # 5e-6: the accuracy of the QP levels (eiquadprog; 3.4e-6 measured at worst here)
            np.testing.assert_allclose(
                achieved(levels[j], v),
                achieved(levels[j], v_cut),
                atol=5e-6,
                rtol=0,
                err_msg=f"level {j} changed by levels below {k} (seed {seed})",
            )


@pytest.mark.parametrize("damping", [0.0, 0.02])
@pytest.mark.parametrize("seed", range(6))
def test_posture_under_feet_and_hands_matches_the_textbook_cascade(talos, seed, damping):
    """The reference stack: the posture of all 32 joints below feet + CoM and both grippers has more
    rows than the 11 DoF left, which it uses all: solved on its Gram matrix (no QR, no basis
    rotation) when well conditioned, it gives the pseudo-inverse recursion's velocity within
    1e-8 per level; the first level (feet factored on the 18 coordinates they touch, then the
    CoM) as well. Damped or not: a well-conditioned level gets no damping either way."""
    rng = np.random.default_rng(100 + seed)
    pool = task_pool(talos, random_configuration(talos, rng), rng)
    pool["bounds"] = wide_bounds(pool, talos.nv)
    # every actuated joint (drawn after the pool so that the other tests' draws are unchanged)
    pool["posture_all"] = {
        "jacobian": np.eye(talos.nv)[6:],
        "lower": rng.normal(0.0, 0.3, talos.nv - 6),
    }
    names = [
        ["bounds"],
        ["left_foot", "right_foot", "com"],
        ["right_gripper", "relative_grippers"],
        ["posture_all"],
    ]
    levels = [[pool[n] for n in level] for level in names]
    v, report = _core.solve_hierarchy(levels, damping=damping)
    assert report["ranks"] == [0, 15, 12, 11]
    assert report["gram_levels"] == [False, False, False, True]
    reference = brute_force_cascade(levels, talos.nv)
    for k, level in enumerate(levels):
        np.testing.assert_allclose(
            achieved(level, v),
            achieved(level, reference),
            atol=TOL,
            rtol=0,
            err_msg=f"level {k} {names[k]} (seed {seed})",
        )
    np.testing.assert_allclose(v, reference, atol=1e-7, rtol=0)


def test_sparse_rows_after_dense_ones_on_a_square_level_solved_on_its_gram_matrix():
    """A first level whose sparse rows (3 rows on coordinates 0-2) are listed after dense ones,
    with as many rows as DoF (10): factored sparse rows first (its rows reordered) and solved on
    its Gram matrix, v must solve the square system A v = b (numpy's solve, κ(A) = 22)."""
    rng = np.random.default_rng(2)
    n = 10
    dense = rng.normal(size=(7, n))
    sparse = np.zeros((3, n))
    sparse[:, :3] = rng.normal(size=(3, 3))
    b = rng.normal(size=n)
    levels = [[{"jacobian": dense, "lower": b[:7]}, {"jacobian": sparse, "lower": b[7:]}]]
    v, report = _core.solve_hierarchy(levels)
    assert report["ranks"] == [n] and report["gram_levels"] == [True]
    np.testing.assert_allclose(
        v, np.linalg.solve(np.vstack([dense, sparse]), b), atol=1e-10, rtol=0
    )
