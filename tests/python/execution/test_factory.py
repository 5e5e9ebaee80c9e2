"""The controller factory against the plan: the TALOS plank controllers are those of fig. 3.13,
references at each step's ends equal the plan's waypoints (computed independently in the
planning problem's own Pinocchio model), and the checks catch bad specs."""

from __future__ import annotations

import copy

import numpy as np
import pinocchio as pin
import pytest

from marionette.control.spec import TaskSpec
from marionette.execution.factory import check_specs, read_specs, write_specs
from marionette.execution.references import compute_references, sample_step
from marionette.planning.problem import load_problem

BALANCE = {("left_sole_link", "se3", ""), ("right_sole_link", "se3", ""), ("com", "com", "")}
RIGHT, LEFT = "gripper_right_base_link", "gripper_left_base_link"

# Fig. 3.13 (thesis 000 §3.4.3), per transition kind of the plan, the active controllers besides
# balance (CoM, feet) and posture: approach and grasp with the right hand, left hand placed
# relative to the right one while it comes to the plank, right hand relative to the left one
# while it lets go, then the left hand alone until it releases the plank.
FIG_3_13 = {
    "Loop | f": set(),
    "talos/right_gripper > plank/H1 | f_01": {("right_gripper", "se3", "")},
    "talos/right_gripper > plank/H1 | f_12": {("right_gripper", "se3", "")},
    "talos/right_gripper > plank/H1 | f_23": {("right_gripper", "se3", "")},
    "talos/right_gripper > plank/H1 | f_34": {("right_gripper", "se3", "")},
    "Loop | 1-0": {("right_gripper", "se3", "")},
    "talos/left_gripper > plank/H8 | 1-0_01": {
        ("right_gripper", "se3", ""),
        ("left_gripper", "relative_se3", RIGHT),
    },
    "talos/left_gripper > plank/H8 | 1-0_12": {
        ("right_gripper", "se3", ""),
        ("left_gripper", "relative_se3", RIGHT),
    },
    "talos/right_gripper < plank/H1 | 0-3:1-0_21": {
        ("left_gripper", "se3", ""),
        ("right_gripper", "relative_se3", LEFT),
    },
    "talos/right_gripper < plank/H1 | 0-3:1-0_10": {("left_gripper", "se3", "")},
    "Loop | 0-3": {("left_gripper", "se3", "")},  # a transit with the left hand alone holding
    "talos/left_gripper < plank/H8 | 0-3_43": {("left_gripper", "se3", "")},
    "talos/left_gripper < plank/H8 | 0-3_32": {("left_gripper", "se3", "")},
    "talos/left_gripper < plank/H8 | 0-3_21": {("left_gripper", "se3", "")},
    "talos/left_gripper < plank/H8 | 0-3_10": set(),
}


@pytest.mark.slow
def test_talos_plank_controllers_are_those_of_fig_3_13(talos_plank):
    seen = set()
    for step, spec in zip(talos_plank.steps, talos_plank.specs):
        assert step.transition in FIG_3_13, f"unexpected transition {step.transition}"
        tasks = {(t.name, t.kind, t.frame_b) for t in spec.tasks}
        assert tasks == BALANCE | FIG_3_13[step.transition] | {("posture", "posture", "")}, (
            step.transition
        )
        levels = {t.name: t.priority for t in spec.tasks}
        assert {levels[n] for n, _, _ in BALANCE} == {0}  # balance first
        assert levels["posture"] == max(levels.values())  # posture last
        grippers = [levels[n] for n, _, _ in FIG_3_13[step.transition]]
        assert all(p == 1 for p in grippers)
        seen.add(step.transition)

    # Every transition of the plank run (a sub-step of no length may be optimised away, a
    # transit added where the plan needs one).
    def transition(name: str) -> str:
        return name.rsplit("_", 1)[0]

    expected = {transition(t) for t in FIG_3_13 if not t.startswith("Loop")}
    assert expected <= {transition(t) for t in seen}, "a transition of the plank run missing"
    kinds = [s.kind for s in talos_plank.steps]
    assert kinds.count("grasp") == 2 and kinds.count("release") == 2
    created = [s.created for s in talos_plank.steps if s.kind == "grasp"]
    released = [s.released for s in talos_plank.steps if s.kind == "release"]
    assert created == [{"talos/right_gripper": "plank/H1"}, {"talos/left_gripper": "plank/H8"}]
    assert released == [{"talos/right_gripper": "plank/H1"}, {"talos/left_gripper": "plank/H8"}]


def test_talos_plank_controllers_pass_their_checks(talos_plank):
    p = talos_plank
    assert check_specs(p.steps, p.specs, p.ctx, p.robot_map) == []


@pytest.mark.parametrize("which", ["ur10_box", pytest.param("talos_plank", marks=pytest.mark.slow)])
def test_references_at_step_ends_equal_the_plan_by_pinocchio(which, request):
    """First and last samples of every streamed reference against the plan's end
    configurations, through the planning problem's combined model (its own frames, with the
    robot's name as prefix, objects included)."""
    p = request.getfixturevalue(which)
    problem = load_problem(p.plan.doc["problem"]["source"])
    pm, pd = problem.model, problem.model.createData()
    for step, spec in zip(p.steps, p.specs):
        traj = sample_step(step, p.robot_map, max_joint_velocity=1.0)
        compute_references(traj, spec, p.model)
        for k, q_plan in ((0, step.q[0]), (-1, step.q[-1])):
            pin.framesForwardKinematics(pm, pd, q_plan)
            for task in (t for t in spec.tasks if t.streamed):  # feet: held, not streamed
                values, _ = traj.references[task.name]
                if task.kind == "se3":
                    X = pd.oMf[pm.getFrameId(f"{p.robot}/{task.frame}")]
                    expected = np.array(
                        [*X.translation, *pin.Quaternion(X.rotation).coeffs()[[3, 0, 1, 2]]]
                    )
                elif task.kind == "relative_se3":
                    Xa = pd.oMf[pm.getFrameId(f"{p.robot}/{task.frame}")]
                    Xb = pd.oMf[pm.getFrameId(f"{p.robot}/{task.frame_b}")]
                    X = Xb.actInv(Xa)
                    expected = np.array(
                        [*X.translation, *pin.Quaternion(X.rotation).coeffs()[[3, 0, 1, 2]]]
                    )
                elif task.kind == "com":
                    # Mass-weighted body centres of the robot's joints (the plank is in this
                    # model too): sum m_i X_Wi c_i / sum m_i.
                    robot_joints = [
                        j for j in range(1, pm.njoints) if pm.names[j].startswith(f"{p.robot}/")
                    ]
                    masses = np.array([pm.inertias[j].mass for j in robot_joints])
                    centres = np.array([pd.oMi[j].act(pm.inertias[j].lever) for j in robot_joints])
                    expected = masses @ centres / masses.sum()
                elif task.kind == "posture":
                    expected = q_plan[p.robot_map.idx]
                got = values[k]
                if len(got) == 7 and np.dot(got[3:], expected[3:]) < 0:
                    expected[3:] *= -1  # q and -q are one rotation
                np.testing.assert_allclose(
                    got, expected, atol=1e-9, err_msg=f"{step.transition} {task.name}"
                )


def test_time_law_keeps_joints_under_the_limit_and_rests_at_both_ends(ur10_box):
    p = ur10_box
    v_max = 0.8
    for step, spec in zip(p.steps, p.specs):
        traj = sample_step(step, p.robot_map, max_joint_velocity=v_max)
        compute_references(traj, spec, p.model)
        q, v = traj.references["posture"]
        speed = np.abs(np.diff(q, axis=0)) / traj.dt
        assert speed.max() <= v_max * 1.01, step.transition
        np.testing.assert_array_equal(v[0], 0.0)
        np.testing.assert_array_equal(v[-1], 0.0)
        # The feed-forward derivative is the derivative of the streamed values.
        fd = (q[2:] - q[:-2]) / (2 * traj.dt)
        np.testing.assert_allclose(v[1:-1], fd, atol=1e-9)
        # The step ends exactly where the next starts (the FSM chains without a jump).
    for a, b in zip(p.steps, p.steps[1:]):
        assert np.linalg.norm(p.robot_map.robot_q(a.q[-1]) - p.robot_map.robot_q(b.q[0])) < 1e-3


def test_a_dwell_holds_the_last_sample_at_rest(ur10_box):
    """A servoed pre-grasp waits (references.dwell): every reference keeps its last value for the
    dwell, with zero derivatives, and the step's duration and time axis grow by it."""
    from marionette.execution.references import dwell

    p = ur10_box
    step, spec = p.steps[1], p.specs[1]
    traj = sample_step(step, p.robot_map, max_joint_velocity=1.0)
    compute_references(traj, spec, p.model)
    before = {n: (v.copy(), d.copy()) for n, (v, d) in traj.references.items()}
    n0, T0 = traj.num_samples, traj.duration
    dwell(traj, 0.25)
    assert traj.num_samples == n0 + 250 and traj.duration == pytest.approx(T0 + 0.25)
    np.testing.assert_allclose(np.diff(traj.t), traj.dt)
    assert len(traj.q) == len(traj.q_plan) == traj.num_samples
    for name, (values, derivatives) in traj.references.items():
        np.testing.assert_array_equal(values[:n0], before[name][0])
        np.testing.assert_array_equal(values[n0:], np.repeat(before[name][0][-1:], 250, axis=0))
        np.testing.assert_array_equal(derivatives[n0:], 0.0)


def test_se3_feedforward_is_the_derivative_of_the_pose(ur10_box):
    """(v, ω) in world axes against a finite difference of the streamed poses."""
    p = ur10_box
    step = max(
        (s for s, sp in zip(p.steps, p.specs) if any(t.kind == "se3" for t in sp.tasks)),
        key=lambda s: len(s.q),
    )
    spec = p.specs[step.index]
    traj = sample_step(step, p.robot_map, max_joint_velocity=1.0)
    compute_references(traj, spec, p.model)
    task = next(t for t in spec.tasks if t.kind == "se3")
    values, derivatives = traj.references[task.name]
    k = len(values) // 3
    X0 = pin.XYZQUATToSE3(np.r_[values[k, :3], values[k, 4:], values[k, 3]])
    X1 = pin.XYZQUATToSE3(np.r_[values[k + 1, :3], values[k + 1, 4:], values[k + 1, 3]])
    omega_world = X0.rotation @ pin.log3(X0.rotation.T @ X1.rotation) / traj.dt
    np.testing.assert_allclose(
        derivatives[k, :3], (X1.translation - X0.translation) / traj.dt, atol=2e-3
    )
    np.testing.assert_allclose(derivatives[k, 3:], omega_world, atol=2e-3)


def test_checks_report_unknown_frames_rank_loss_and_dead_ends(ur10_box):
    p = ur10_box
    specs = copy.deepcopy(p.specs)
    steps = copy.deepcopy(p.steps)
    specs[1].tasks.append(TaskSpec("nowhere", "se3", 0, frame="no_such_link"))
    g = next(t for t in specs[2].tasks if t.kind == "se3")
    specs[2].tasks.append(TaskSpec("twice", "se3", g.priority, frame=g.frame))  # 12 rows, rank 6
    steps[4].q = steps[4].q.copy()
    steps[4].q[:, p.robot_map.idx[0]] += 0.3  # a gap of 0.3 rad
    problems = check_specs(steps, specs, p.ctx, p.robot_map)
    assert any("unknown frame 'no_such_link'" in m and m.startswith("step 1") for m in problems)
    assert any("loses rank" in m and m.startswith("step 2") for m in problems)
    assert any("step 3 ends" in m for m in problems) and any("step 4 ends" in m for m in problems)


def test_spec_file_round_trips(ur10_box, tmp_path):
    p = ur10_box
    path = write_specs(tmp_path / "controllers.yaml", p.steps, p.specs, "ur10_box")
    text = path.read_text()
    assert "grasp_at_end" in text and "ur10/gripper" in text
    assert [s.to_dict() for s in read_specs(path)] == [s.to_dict() for s in p.specs]


def test_a_gripper_on_fewer_joints_than_its_task_rows_loses_no_rank_it_could_have():
    """The SO-101 moves its gripper with 5 joints: its se3 task (6 rows) has rank 5 at best, and
    the check asks no more of it; the same task twice on a level still loses rank (10 of 5)."""
    from marionette import robots
    from marionette.control.spec import ControllerSpec
    from marionette.execution.factory import level_conditioning

    model, _ = robots.load_pinocchio("so101", with_collision=False)
    q = robots.reference_configuration("so101", model)
    one = [TaskSpec("g", "se3", 0, frame="gripper_link"), TaskSpec("posture", "posture", 0)]
    (level,) = level_conditioning(model, model.createData(), ControllerSpec(1, "one", one), q)
    assert (level.rows, level.rank, level.attainable) == (6, 5, 5)
    twice = [*one, TaskSpec("h", "se3", 0, frame="gripper_link")]
    (level,) = level_conditioning(model, model.createData(), ControllerSpec(2, "two", twice), q)
    assert level.rank == 5 and level.attainable == 10


def test_a_gripper_changing_its_grip_holds_the_arm_at_the_step_start(ur10_box):
    """Friction grasps (§3.2.5.1): the step after the grasp starts with the arm at rest while the
    fingers close over their whole stroke (robot.yaml: 4 cm at 2 cm/s, ramp 0.2 m/s^2) and the
    force settles (0.5 s); the release step likewise while they open; no other step waits."""
    from marionette.execution.factory import build_specs, context_from_plan
    from marionette.execution.references import GRIP_SETTLE_S
    from marionette.execution.supervisor import SupervisorOptions, prepare_trajectories

    p = ur10_box
    ctx = context_from_plan(p.plan.doc, p.robot, p.model, gripper_admittance=True)
    specs = build_specs(p.steps, ctx)
    options = SupervisorOptions(max_joint_velocity=1.0)
    with_grip = prepare_trajectories(p.steps, specs, p.robot_map, options)
    without = prepare_trajectories(p.steps, p.specs, p.robot_map, options)  # no admittance
    expected = 0.04 / 0.02 + 0.02 / 0.2 + GRIP_SETTLE_S
    kinds = [s.kind for s in p.steps]
    grasp, release = kinds.index("grasp"), kinds.index("release")
    for step in p.steps:
        a, b = with_grip[step.index], without[step.index]
        waits = step.index in (grasp + 1, release)
        lead = expected if waits else 0.0
        assert a.duration == pytest.approx(b.duration + lead, abs=1e-9), step.transition
        n = round(lead / a.dt)
        np.testing.assert_allclose(np.diff(a.t), a.dt)
        np.testing.assert_array_equal(a.q[:n], np.repeat(b.q[:1], n, axis=0))
        np.testing.assert_array_equal(a.q[n:], b.q)
        for name, (values, derivatives) in a.references.items():
            if name not in b.references:
                continue
            np.testing.assert_array_equal(values[n:], b.references[name][0])
            np.testing.assert_array_equal(derivatives[:n], 0.0)
