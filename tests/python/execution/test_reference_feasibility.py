"""Every reference the supervisor streams respects the joints' velocity limits (the URDF's, which
the controller's safety filter clamps at) and the scenario's max_joint_velocity, also after a
rewrite made a step faster (the gaze turning TALOS's head within a short first step): such a step
is re-timed. Steps are generated — random joint-space paths, short and long, on every bundled
robot — and what reaches the controller is read back from the chunks the real streamer sends."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette import robots
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.plan_steps import PlanRobotMap, Step
from marionette.execution.references import StepTiming, shaped_trajectory, velocity_limits
from marionette.execution.streamer import ReferenceStreamer
from marionette.execution.visual_servo import head_gaze_posture

ROBOTS = ("ur5", "ur10", "panda", "talos")


def _layout(model: pin.Model, robot: str) -> list[str]:
    out = []
    for j in range(1, model.njoints):
        name = f"{robot}/{model.names[j]}"
        n = model.joints[j].nq
        out += (
            [name] if n == 1 else [f"{name}.{c}" for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
        )
    return out


def _step(q: np.ndarray) -> Step:
    return Step(0, "t", "t", "a", "b", "a", {}, {}, {}, {}, {}, [0], q)


def _random_step(model: pin.Model, rng: np.random.Generator, length: float) -> np.ndarray:
    """A polyline of 2-6 configurations from a random start, ``length`` rad long in all."""
    q0 = pin.neutral(model)
    q0 = pin.integrate(model, q0, rng.uniform(-1.0, 1.0, model.nv))
    q = [q0]
    n = int(rng.integers(1, 6))
    for _ in range(n):
        d = rng.normal(size=model.nv)
        q.append(pin.integrate(model, q[-1], d / np.linalg.norm(d) * length / n))
    return np.array(q)


def _wobble(joint_v: int, amplitude: float):
    """A rewrite that is a function of the path's normalised time (as the gaze is): joint
    ``joint_v`` of the posture reference swings by ``amplitude`` twice over the step."""

    def rewrite(step, traj, first):
        values, derivatives = traj.references["posture"]
        u = np.linspace(0.0, 1.0, len(values))
        values[:, joint_v] += amplitude * np.sin(2 * np.pi * u) ** 2
        derivatives[1:-1, joint_v] = (values[2:, joint_v] - values[:-2, joint_v]) / (2 * traj.dt)

    return rewrite


def _streamed(traj, dt_us: int = 1000) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The samples the real streamer sends, per task, rebuilt from its chunks."""
    chunks = []
    streamer = ReferenceStreamer(chunks.append, 1, traj.references, 0, dt_us, 200, 4.0)
    now = 0
    while not streamer.done:
        streamer.pump(now)
        now += 100_000
    out = {}
    for name in traj.references:
        mine = sorted((c for c in chunks if c.task_name == name), key=lambda c: c.utime)
        out[name] = (
            np.vstack([np.array(c.value) for c in mine]),
            np.vstack([np.array(c.derivative) for c in mine]),
        )
    return out


def _check_within_limits(model: pin.Model, traj, streamed, v_max: float) -> None:
    values, derivatives = streamed["posture"]
    assert len(values) == traj.num_samples
    # finite differences with Pinocchio (free flyer included), against both bounds as stated
    v = np.array([pin.difference(model, a, b) for a, b in zip(values, values[1:])]) / traj.dt
    urdf = np.where(
        np.isfinite(model.velocityLimit) & (model.velocityLimit > 0), model.velocityLimit, np.inf
    )
    for speeds, what in ((np.abs(v), "differences"), (np.abs(derivatives), "feed-forward")):
        assert speeds.max() <= v_max * (1 + 1e-6), (what, speeds.max())
        worst = np.max(speeds / urdf, axis=0)
        assert worst.max() <= 1.0 + 1e-6, (what, model.names, worst)


@pytest.mark.slow
@pytest.mark.parametrize("robot", ROBOTS)
def test_generated_steps_stream_within_the_joint_limits_once_re_timed(robot):
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    robot_map = PlanRobotMap(_layout(model, robot), model, robot)
    frame = robots.semantics(robot).grippers[0].link
    spec = ControllerSpec(
        1,
        "s",
        [
            TaskSpec("hand", "se3", 0, frame=frame, streamed=True),
            TaskSpec("posture", "posture", 1, streamed=True),
        ],
    )
    rng = np.random.default_rng(sum(map(ord, robot)))
    v_max = 0.7
    limits = velocity_limits(model, v_max)
    retimed = 0
    first_joint = 6 if model.joints[1].nv == 6 else 0
    for length in (0.01, 0.3, 3.0):  # short, medium, long
        for _ in range(2):
            q = _random_step(model, rng, length)
            j = int(rng.integers(first_joint, model.nv))
            rewrite = _wobble(j, float(rng.uniform(0.05, 0.6)))
            traj = shaped_trajectory(
                _step(q), spec, robot_map, limits, 1e-3, 0.5, StepTiming(), [rewrite]
            )
            retimed += traj.retimed > 1.0
            _check_within_limits(model, traj, _streamed(traj), v_max)
            # the path is kept: it starts and ends where it was planned, at rest
            np.testing.assert_allclose(traj.q[0], q[0], atol=1e-12)
            np.testing.assert_allclose(traj.q[-1], q[-1], atol=1e-12)
    assert retimed >= 3  # the short steps could not take their wobble at the time law's pace


def test_a_gaze_ramped_in_over_a_short_first_step_is_re_timed():
    """The plank-flip failure: the head turned towards the object within a 0.5 s first step
    asked head_1_joint for more than its 1 rad/s; the step now lasts long enough."""
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    robot_map = PlanRobotMap(_layout(model, "talos"), model, "talos")
    q0 = model.referenceConfigurations["half_sitting"]
    q1 = q0.copy()
    q1[model.joints[model.getJointId("arm_right_4_joint")].idx_q] -= 0.05
    spec = ControllerSpec(1, "s", [TaskSpec("posture", "posture", 0, streamed=True)])
    camera = robots.robot("talos").camera_frame
    head = robots.robot("talos").calibration_head_joints

    def gaze(step, traj, first):  # look down-left at a point on the table
        targets = np.tile([0.5, 0.4, 0.7], (traj.num_samples, 1))
        head_gaze_posture(model, traj, targets, camera, head, ramp_in=first)

    limits = velocity_limits(model, 0.5)
    traj = shaped_trajectory(
        _step(np.array([q0, q1])), spec, robot_map, limits, 1e-3, 0.5, StepTiming(), [gaze], True
    )
    assert traj.retimed > 1.5 and traj.retimed_for.startswith("head_")
    _check_within_limits(model, traj, _streamed(traj), 0.5)
    # the head does reach the gaze: the rewrite is applied, only slower
    head = model.joints[model.getJointId("head_1_joint")].idx_q
    assert abs(traj.references["posture"][0][-1, head] - q0[head]) > 0.2


def _jump(joint_v: int, height: float):
    """A rewrite whose reference jumps by ``height`` halfway (a gaze switching joints on):
    its velocity is the jump over a sample, whatever the step's pace."""

    def rewrite(step, traj, first):
        values, derivatives = traj.references["posture"]
        half = len(values) // 2
        values[half:, joint_v] += height
        derivatives[1:-1, joint_v] = (values[2:, joint_v] - values[:-2, joint_v]) / (2 * traj.dt)

    return rewrite


@pytest.mark.parametrize("robot", ROBOTS)
def test_a_rewrite_that_jumps_or_asks_too_much_is_refused_without_growing(robot):
    """Re-timing a jump multiplied the samples by its excess at every attempt (a demo took
    21 GB before the kernel killed it): refused at the second attempt, the samples bounded;
    a rewrite that would need the step to last more than max_duration_s is refused too."""
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    robot_map = PlanRobotMap(_layout(model, robot), model, robot)
    spec = ControllerSpec(1, "s", [TaskSpec("posture", "posture", 0, streamed=True)])
    rng = np.random.default_rng(7)
    q = _random_step(model, rng, 0.3)
    j = model.nv - 1
    limits = velocity_limits(model, 0.5)
    seen: list[int] = []

    def counting(step, traj, first):
        seen.append(traj.num_samples)

    with pytest.raises(ValueError, match="whatever the step's pace") as e:
        shaped_trajectory(
            _step(q), spec, robot_map, limits, 1e-3, 0.5, StepTiming(), [_jump(j, 0.003), counting]
        )
    assert "\n" not in str(e.value)
    assert len(seen) == 2 and max(seen) <= 600_000  # 600 s at 1 kHz
    # a swing far beyond the joint's bound: within it the step would last an hour
    with pytest.raises(ValueError, match=r"would last \d+ s \(more than 600 s\)"):
        shaped_trajectory(
            _step(q), spec, robot_map, limits, 1e-3, 0.5, StepTiming(), [_wobble(j, 500.0)]
        )
