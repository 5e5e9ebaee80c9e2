"""Task errors split by unit (position, orientation, joints, gripper, image) and every axis of
the report plots labelled with its unit, on synthetic runs of every bundled robot: known pose
offsets between the recorded motion and the streamed references must come back as the same
millimetres and degrees, each on its own axis, live and replayed from a log. The plots of the
other scenarios (grip force, deburr, drill, grasp-walk, step-over) are drawn from synthetic data
and their axes checked the same way."""

from __future__ import annotations

import re
from types import SimpleNamespace

import matplotlib
import numpy as np
import pinocchio as pin
import pytest

from marionette import robots
from marionette.control.spec import TaskSpec
from marionette.execution.references import StepTrajectory
from marionette.scenarios import plan_and_execute_report as report
from marionette.scenarios.task_error_plot import (
    JOINT,
    MEASURED,
    MIXED,
    ORIENTATION,
    POSITION,
    StepTasks,
    pose,
    split_by_unit,
)

matplotlib.use("Agg")

UNIT = re.compile(r"\[[^\[\]]+\]")
LENGTH = re.compile(r"\[(m|mm)\]")
ANGLE = re.compile(r"\[(rad|deg|°)\]")


@pytest.fixture
def figures(monkeypatch):
    """Every matplotlib figure the code under test saves, kept instead of rendered (the labels
    are what is checked; rendering PNGs would be most of the test's time)."""
    from matplotlib.figure import Figure

    saved: list[Figure] = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, *args, **kwargs: saved.append(fig))
    return saved


def assert_every_axis_has_units(figs) -> None:
    assert figs
    for fig in figs:
        for ax in fig.axes:
            where = f"{fig.get_suptitle() or ax.get_title()!r}, axes {ax.get_ylabel()!r}"
            assert UNIT.search(ax.get_xlabel()), f"x label without [unit]: {where}"
            assert UNIT.search(ax.get_ylabel()), f"y label without [unit]: {where}"
            assert not (LENGTH.search(ax.get_ylabel()) and ANGLE.search(ax.get_ylabel())), where


def body_frames(model: pin.Model) -> list[str]:
    return [f.name for f in model.frames if f.type == pin.FrameType.BODY]


def rows(poses: list[pin.SE3]) -> np.ndarray:
    out = []
    for X in poses:
        quat = pin.Quaternion(X.rotation)
        out.append([*X.translation, quat.w, quat.x, quat.y, quat.z])
    return np.array(out)


def offset(rng: np.random.Generator, metres: float, radians: float) -> pin.SE3:
    """A pose whose translation has norm ``metres`` and rotation angle ``radians``."""
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    return pin.SE3(
        pin.exp3(radians * axis / np.linalg.norm(axis)),
        metres * direction / np.linalg.norm(direction),
    )


def synthetic_run(robot: str, seed: int):
    """Two steps of a robot moving between random configurations; per step, an se3 and a
    relative_se3 task whose streamed references sit at known offsets Δ from the recorded motion
    (X_D = X_F Δ⁻¹, so E = X_D⁻¹ X_F = Δ), a held se3 task, com, posture, gripper admittance and
    a pbvs task (reference corrected by vision: unknown to the plot)."""
    rng = np.random.default_rng(seed)
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    data = model.createData()
    frames = body_frames(model)
    q0 = robots.reference_configuration(robot, model)
    dt, duration = 0.01, 1.5
    t_step = np.arange(0.0, duration + 1e-9, dt)
    truth: dict[tuple[int, str], tuple[float, float]] = {}
    steps, specs, records, trajectories = [], [], [], {}
    utimes, qs = [], []
    for k in range(2):
        q1 = pin.integrate(model, q0, 0.4 * rng.normal(size=model.nv))
        q = np.array([pin.interpolate(model, q0, q1, s) for s in t_step / duration])
        t0 = 10.0 + k * (duration + 0.5)
        hand, other, held = rng.choice(frames, 3, replace=False)
        tasks = [
            TaskSpec("hand", "se3", 1, frame=hand, streamed=True),
            TaskSpec("hands", "relative_se3", 1, frame=hand, frame_b=other, streamed=True),
            TaskSpec("held", "se3", 0, frame=held),
            TaskSpec("com", "com", 0),
            TaskSpec("posture", "posture", 2),
            TaskSpec("jaw", "gripper_admittance", 1, joints=("jaw",)),
            TaskSpec("camera", "pbvs", 1, frame=hand, streamed=True),
        ]
        deltas = {}
        references = {}
        for name, frame_b in (("hand", None), ("hands", other)):
            metres, radians = rng.uniform(1e-3, 2e-2), rng.uniform(1e-3, 5e-2)
            truth[(k, name)] = (metres * 1e3, np.degrees(radians))
            deltas[name] = offset(rng, metres, radians)
            X = []
            for qk in q:
                pin.framesForwardKinematics(model, data, qk)
                X_F = data.oMf[model.getFrameId(hand)]
                if frame_b is not None:
                    X_F = data.oMf[model.getFrameId(frame_b)].actInv(X_F)
                X.append(X_F * deltas[name].inverse())
            references[name] = (rows(X), np.zeros((len(X), 6)))
        trajectories[k] = StepTrajectory(dt, duration, t_step, q, q, references)
        trace = []
        for i, t in enumerate(t_step):
            decay = np.exp(-3 * t)
            trace.append(
                (
                    round((t0 + t) * 1e6),
                    {
                        "hand": float(np.linalg.norm(pin.log6(deltas["hand"]).vector)),
                        "hands": float(np.linalg.norm(pin.log6(deltas["hands"]).vector)),
                        "held": 1e-4 * i,
                        "com": 0.02 * decay,
                        "posture": 0.3 * decay,
                        "jaw": 0.1 * decay,
                        "camera": 0.05 * decay,
                    },
                )
            )
        utimes += [u for u, _ in trace]
        qs += list(q)
        steps.append(SimpleNamespace(index=k))
        specs.append(SimpleNamespace(tasks=tasks))
        records.append(
            SimpleNamespace(
                index=k,
                controller_id=100 + k,
                utime_start=round(t0 * 1e6),
                utime_reference_start=round(t0 * 1e6),
                error_trace=trace,
            )
        )
        q0 = q1
    supervisor = SimpleNamespace(
        steps=steps,
        specs=specs,
        trajectories=trajectories,
        robot_map=SimpleNamespace(
            robot=robot, object_pose=lambda q, name: pin.SE3(np.eye(3), q[:3])
        ),
    )
    recorder = SimpleNamespace(
        utimes=utimes,
        q=qs,
        objects=[{"box": np.array([*q[:3], 1.0, 0, 0, 0])} for q in qs],
    )
    return model, supervisor, SimpleNamespace(records=records), recorder, truth


@pytest.mark.parametrize("robot", robots.robot_names())
def test_pose_errors_come_back_as_the_offsets_in_mm_and_degrees(robot):
    model, supervisor, result, recorder, truth = synthetic_run(robot, seed=len(robot))
    steps = report.run_task_steps(result.records, supervisor)
    panels = split_by_unit(steps, model, np.array(recorder.utimes) * 1e-6, np.array(recorder.q))
    assert set(panels[MIXED]) == {"camera"}  # only the task whose reference is unknown
    for k in range(2):
        for name in ("hand", "hands"):
            mm, deg = truth[(k, name)]
            measured = name + MEASURED
            assert np.allclose(panels[POSITION][measured][k][1], mm, rtol=1e-6), (k, name)
            assert np.allclose(panels[ORIENTATION][measured][k][1], deg, rtol=1e-6), (k, name)
        _, held_mm = panels[POSITION]["held" + MEASURED][k]
        assert held_mm[0] == pytest.approx(0.0, abs=1e-9)  # held since the switch
    assert np.allclose(
        panels[POSITION]["com"][0][1], [1e3 * e["com"] for _, e in result.records[0].error_trace]
    )
    assert "posture" not in panels[POSITION] and "com" not in panels[ORIENTATION]
    assert "hand" not in panels[POSITION]  # a pose task's norm mixes units: never plotted as is


def test_a_position_mask_leaves_no_orientation_and_a_fixed_reference_is_used():
    model, _ = robots.load_pinocchio("ur5", with_collision=False)
    data = model.createData()
    frame = body_frames(model)[-1]
    q = np.array([robots.reference_configuration("ur5", model)] * 3)
    pin.framesForwardKinematics(model, data, q[0])
    target = data.oMf[model.getFrameId(frame)] * offset(np.random.default_rng(3), 0.01, 0.2)
    (ref,) = rows([target])
    tasks = {
        "xyz": TaskSpec("xyz", "se3", 0, frame=frame, mask=(True,) * 3, reference=tuple(ref)),
        "fixed": TaskSpec("fixed", "se3", 0, frame=frame, reference=tuple(ref)),
    }
    step = StepTasks([(0, {"xyz": 1.0, "fixed": 1.0}), (20_000, {"xyz": 1.0, "fixed": 1.0})], tasks)
    panels = split_by_unit([step], model, np.array([0.0, 0.01, 0.02]), q)
    xyz, fixed = "xyz" + MEASURED, "fixed" + MEASURED
    assert set(panels[POSITION]) == {xyz, fixed} and set(panels[ORIENTATION]) == {fixed}
    assert np.allclose(panels[POSITION][fixed][0][1], 10.0)
    assert np.allclose(panels[ORIENTATION][fixed][0][1], np.degrees(0.2))
    assert pose(ref).isApprox(target)


@pytest.mark.parametrize("robot", ["ur10", "talos"])  # an arm; a humanoid (CoM over its feet)
def test_every_axis_of_the_plan_and_execute_report_has_its_unit(robot, tmp_path, figures):
    model, supervisor, result, recorder, _ = synthetic_run(robot, seed=7)
    feet = ("left", "right") if robots.semantics(robot).contacts else ()
    scenario = SimpleNamespace(name="synthetic", object_name="box", feet=feet)
    paths = report._plots(tmp_path, scenario, supervisor, result, recorder, model)
    expected = ["task_errors.png", "joints.png", "object_path.png"]
    assert [p.name for p in paths] == expected + (["com_support.png"] if feet else [])
    assert_every_axis_has_units(figures)
    errors = figures[0]
    labels = [ax.get_ylabel() for ax in errors.axes]
    assert POSITION in labels and ORIENTATION in labels
    for ax in errors.axes:
        names = {line.get_label() for line in ax.get_lines() if not line.get_label()[0] == "_"}
        if ax.get_ylabel() == MIXED:
            assert names == {"camera"}


def test_every_axis_of_the_other_scenario_plots_has_its_unit(tmp_path, figures):
    from marionette.execution.grip_force import GripForceRecorder
    from marionette.scenarios import deburr, drill

    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    grip = GripForceRecorder(model, {"left": None, "right": None})
    t = list(np.linspace(0.0, 3.0, 30))
    grip.t, grip.estimate = t, {"left": [5.0] * 30, "right": [4.0] * 30}
    grip.contact = {"left": [5.1] * 30, "right": [3.9] * 30}
    grip.plot(tmp_path / "grip.png", 5.0, {"left": [(1.0, 2.0)]})
    holes = {f"part/hole{i}": pin.SE3(np.eye(3), np.array([0.0, 0.1 * i, 0.05])) for i in range(3)}
    deburr._plot(
        tmp_path,
        {
            "seed": 1,
            "summary": "synthetic",
            "settings": {"position_tolerance_m": 2e-4, "angle_tolerance_deg": 0.5},
            "holes": [
                {
                    "hole": h,
                    "axis_distance_m": 1e-4,
                    "open_loop_axis_distance_m": 3e-3,
                    "axis_angle_deg": 0.1,
                    "open_loop_axis_angle_deg": 1.0,
                }
                for h in holes
            ],
            "tour": {"order": list(holes)},
        },
        holes,
    )
    drill._plot(
        tmp_path,
        {
            "seed": 1,
            "settings": {"position_tolerance_m": 1e-3, "angle_tolerance_deg": 1.0},
            "holes": [
                {"hole": h, "reference": i < 2, "position_error_m": 5e-4, "angle_error_deg": 0.3}
                for i, h in enumerate(holes)
            ],
        },
    )
    assert len(figures) == 3
    assert_every_axis_has_units(figures)


def test_a_replayed_reference_is_its_chunks_a_later_one_overriding_from_its_start():
    from marionette.control.spec import reference_chunk
    from marionette.viewer.replay import _references

    first = reference_chunk(5, "hand", 1_000_000, np.zeros((200, 3)), dt_us=1000)
    later = reference_chunk(5, "hand", 1_150_000, np.ones((200, 3)), dt_us=1000, sequence=1)
    other = reference_chunk(6, "com", 2_000_000, np.full((10, 3), 2.0), dt_us=1000)
    refs = _references([first, later, other])
    t, values = refs[5]["hand"]
    assert len(t) == 350 and np.all(np.diff(t) > 0)
    assert t[0] == pytest.approx(1.0) and t[-1] == pytest.approx(1.349)
    assert np.all(values[:150] == 0.0) and np.all(values[150:] == 1.0)
    assert refs[6]["com"][1].shape == (10, 3)


def test_a_replayed_run_splits_its_pose_errors_from_the_log_alone(tmp_path, figures):
    """``marionette replay``'s re-plot: tasks from CONTROLLER_SPEC, references from
    TASK_REFERENCE, the motion from ROBOT_STATE; a known offset comes back in mm and degrees."""
    import lcm
    from marionette import (
        channels,
        lcmt_controller_status,
        lcmt_robot_state,
        lcmt_supervisor_decision,
    )
    from marionette.control.spec import ControllerSpec, reference_chunk
    from marionette.viewer.replay import replot_report

    rng = np.random.default_rng(11)
    model, _ = robots.load_pinocchio("ur5", with_collision=False)
    data = model.createData()
    frame = body_frames(model)[-1]
    q0 = robots.reference_configuration("ur5", model)
    q = np.array([q0 + s * rng.normal(size=model.nq) * 0.3 for s in np.linspace(0, 1, 100)])
    delta = offset(rng, 0.004, 0.03)
    X_D = []
    for qk in q:
        pin.framesForwardKinematics(model, data, qk)
        X_D.append(data.oMf[model.getFrameId(frame)] * delta.inverse())
    u0, dt_us = 5_000_000, 10_000
    tasks = [
        TaskSpec("hand", "se3", 0, frame=frame, streamed=True),
        TaskSpec("posture", "posture", 1),
    ]
    log = lcm.EventLog(str(tmp_path / "run.lcmlog"), "w", overwrite=True)

    def write(utime: int, channel: str, msg) -> None:
        log.write_event(utime, channel, msg.encode())

    write(u0, channels.CONTROLLER_SPEC, ControllerSpec(7, "step", tasks).to_lcm())
    for seq, (event, inputs) in enumerate(
        (("step_started", {"controller_id": 7.0}), ("switch_accepted", {}))
    ):
        d = lcmt_supervisor_decision()
        d.utime, d.seq, d.step_index, d.event = u0, seq, 0, event
        d.input_name, d.input_value = list(inputs), list(inputs.values())
        d.num_inputs = len(inputs)
        write(u0, channels.SUPERVISOR_DECISION, d)
    write(u0, channels.TASK_REFERENCE, reference_chunk(7, "hand", u0, rows(X_D), dt_us=dt_us))
    names = [model.names[j] for j in range(1, model.njoints)]
    for k, qk in enumerate(q):
        utime = u0 + k * dt_us
        state = lcmt_robot_state()
        state.utime, state.robot_name, state.num_joints, state.joint_name = utime, "ur5", 6, names
        state.joint_position, state.joint_velocity = list(qk), [0.0] * 6
        state.joint_effort, state.base_quaternion = [0.0] * 6, [1.0, 0.0, 0.0, 0.0]
        write(utime, channels.ROBOT_STATE, state)
        status = lcmt_controller_status()
        status.utime, status.active_controller_id, status.num_tasks = utime, 7, 2
        status.task_name, status.task_error_norm = ["hand", "posture"], [0.1, 0.2]
        write(utime, channels.CONTROLLER_STATUS, status)
    log.close()
    paths = replot_report(tmp_path / "run.lcmlog", tmp_path / "replot", every=1)
    assert [p.name for p in paths] == ["task_errors.png"]
    assert_every_axis_has_units(figures)
    by_label = {ax.get_ylabel(): ax for ax in figures[0].axes}
    assert set(by_label) == {POSITION, ORIENTATION, JOINT}

    def hand(panel: str) -> np.ndarray:
        (line,) = [ln for ln in by_label[panel].get_lines() if ln.get_label() == "hand" + MEASURED]
        return np.asarray(line.get_ydata())

    assert np.allclose(hand(POSITION), 4.0, rtol=1e-6)
    assert np.allclose(hand(ORIENTATION), np.degrees(0.03), rtol=1e-6)


def test_every_axis_of_the_walking_plots_has_its_unit(tmp_path, figures):
    """grasp-walk and step-over plots of a synthetic walk: three steps planned, statuses through
    the swing phases, standing TALOS states with both soles loaded."""
    from marionette import (
        lcmt_footstep,
        lcmt_footstep_plan,
        lcmt_robot_state,
        lcmt_walk_status,
    )
    from marionette.scenarios import grasp_walk, step_over
    from marionette.scenarios.walking_scenario import WalkRecorder

    model, _ = robots.load_pinocchio("talos", with_collision=False)
    client = SimpleNamespace(bus=SimpleNamespace(subscribe=lambda *args: None))
    rec = WalkRecorder(client, model)
    plan = lcmt_footstep_plan()
    plan.plan_id, plan.num_steps, plan.stop_at_end = 1, 3, True
    for i in range(3):
        step = lcmt_footstep()
        step.index, step.is_left, step.x, step.y = i, i % 2 == 0, 0.1 * (i + 1), 0.1 - 0.2 * (i % 2)
        plan.steps.append(step)
    q = robots.reference_configuration("talos", model)
    names = [model.names[j] for j in range(2, model.njoints)]
    phases = ["double_support", "left_swing", "double_support", "right_swing", "standing"]
    for k in range(50):
        utime = 1_000_000 + k * 20_000
        state = lcmt_robot_state()
        state.utime, state.robot_name = utime, "talos"
        state.num_joints, state.joint_name = len(names), names
        state.joint_position = [float(q[model.joints[model.getJointId(n)].idx_q]) for n in names]
        state.joint_velocity = state.joint_effort = [0.0] * len(names)
        state.base_position, state.base_quaternion = list(q[:3]), [1.0, 0.0, 0.0, 0.0]
        state.num_contacts = 2
        state.contact_frame = ["left_sole_link", "right_sole_link"]
        state.contact_wrench = [[0.0, 0.0, 400.0, 0.0, 0.0, 0.0]] * 2
        rec._on_state(state)
        status = lcmt_walk_status()
        status.utime, status.phase = utime, phases[min(k // 10, 4)]
        status.com = [0.01 * k / 50, 0.0, 0.87]
        status.zmp_reference = status.zmp_measured = [0.01 * k / 50, 0.0]
        status.left_foot, status.right_foot = [0.0, 0.1, 0.0, 0.0], [0.0, -0.1, 0.0, 0.0]
        rec._on_status(status)
        if k == 0:
            rec._on_plan(plan)
    grasp_walk._plots(
        tmp_path, rec, np.array([0.5, 0.0, 0.8]), np.array([0.6, 0.1, 0.8]), 1_500_000, model
    )
    bar = np.array([0.3, 0.0, 0.0])
    step_over._plots(
        tmp_path,
        rec,
        [(1_000_000, bar + 0.1), (1_500_000, bar)],
        bar,
        bar + 0.1,
        np.array([0.8, 0.0, 0.0]),
        model,
        step_over.StepOverSettings(),
    )
    assert len(figures) == 6
    assert_every_axis_has_units(figures)
