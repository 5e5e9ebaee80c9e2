"""marionette-controller on TALOS in MuJoCo, driven over LCM like the supervisor does:
standing still under a balance stack, reaching a gripper target with feet and CoM held, and
swapping controllers (a continuous swap is accepted, a discontinuous one refused)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from marionette import robots
from marionette.control.client import configuration_from_state, pose_to_vector
from marionette.control.spec import ControllerSpec, TaskSpec, reference_chunk

TALOS = robots.robot("talos")


@pytest.fixture(scope="module")
def talos():
    model, _ = robots.load_pinocchio("talos", with_collision=False)
    return model, model.createData()


def frame_pose(talos, q, frame):
    model, data = talos
    pin.framesForwardKinematics(model, data, q)
    return pin.SE3(data.oMf[model.getFrameId(frame)])


def balance_tasks(priority: int = 0) -> list[TaskSpec]:
    """Feet fixed and CoM held where they are (empty references: the current values)."""
    return [
        TaskSpec("left_foot", "se3", priority, frame="left_sole_link", gain=10.0),
        TaskSpec("right_foot", "se3", priority, frame="right_sole_link", gain=10.0),
        TaskSpec("com", "com", priority, gain=10.0),
    ]


def stack(controller_id: int, gripper: bool = False, posture_gain: float = 1.0) -> ControllerSpec:
    tasks = balance_tasks(0)
    if gripper:  # follows a streamed reference, holding its current pose until one arrives
        tasks.append(
            TaskSpec(
                "right_gripper", "se3", 1, frame="gripper_right_base_link", gain=5.0, streamed=True
            )
        )
    tasks.append(TaskSpec("posture", "posture", 2, gain=posture_gain))
    return ControllerSpec(
        controller_id, f"stack{controller_id}", tasks, max_switch_velocity_jump=0.05
    )


@pytest.mark.slow
def test_talos_stands_then_reaches_a_target_10cm_away(run_controller, talos):
    scene = str(TALOS.mjcf)
    with run_controller(
        "--robot", "talos", "--scene", scene, "--speed", "0", "--camera-rate", "0"
    ) as c:
        q_start = configuration_from_state(talos[0], c.state)
        c.send_spec(stack(1))
        c.wait(
            lambda c: c.status.mode == "running" and c.status.active_controller_id == 1,
            30.0,
            "the first controller",
        )
        c.wait_time(10.0)
        q = configuration_from_state(talos[0], c.state)
        assert np.linalg.norm(q[:2] - q_start[:2]) < 0.01, "base drift over 10 s of standing"
        assert abs(q[2] - q_start[2]) < 0.01, "the robot did not sink or fall"
        for foot in ("left_sole_link", "right_sole_link"):
            moved = (
                frame_pose(talos, q, foot).translation
                - frame_pose(talos, q_start, foot).translation
            )
            assert np.linalg.norm(moved) < 0.005, f"{foot} moved {moved}"

        # A gripper target 10 cm ahead (world x), same orientation, reached along a minimum-jerk
        # path of 2 s streamed in 1 ms samples (as the supervisor streams a planned path).
        start = frame_pose(talos, q, "gripper_right_base_link")
        target = pin.SE3(start.rotation, start.translation + np.array([0.10, 0.0, 0.0]))
        c.send_spec(stack(2, gripper=True))
        c.wait(lambda c: c.status.active_controller_id == 2, 30.0, "the reaching controller")
        t0 = c.utime() + 20_000
        s_ = np.linspace(0.0, 1.0, 2001)
        blend = 10 * s_**3 - 15 * s_**4 + 6 * s_**5
        rate = (30 * s_**2 - 60 * s_**3 + 30 * s_**4) / 2.0  # d(blend)/dt over 2 s
        values = np.array(
            [
                pose_to_vector(
                    pin.SE3(start.rotation, start.translation + b * np.array([0.1, 0, 0]))
                )
                for b in blend
            ]
        )
        derivatives = np.zeros((len(s_), 6))
        derivatives[:, 0] = 0.1 * rate
        for k in range(0, len(s_), 1000):
            c.send_reference(
                reference_chunk(
                    2,
                    "right_gripper",
                    t0 + 1000 * k,
                    values[k : k + 1000],
                    derivatives[k : k + 1000],
                    last=k + 1000 >= len(s_),
                )
            )
        c.wait_time(6.0)
        q = configuration_from_state(talos[0], c.state)
        reached = frame_pose(talos, q, "gripper_right_base_link")
        assert np.linalg.norm(reached.translation - target.translation) < 0.01
        assert c.task_error("right_gripper") < 0.01
        for foot in ("left_sole_link", "right_sole_link"):
            moved = (
                frame_pose(talos, q, foot).translation
                - frame_pose(talos, q_start, foot).translation
            )
            assert np.linalg.norm(moved) < 0.005, f"{foot} moved {moved} while reaching"
        assert c.status.num_refused_switches == 0
        assert c.status.mode == "running"


@pytest.mark.slow
def test_simulated_grasp_carries_the_plank_and_release_lets_it_go(run_controller, talos):
    """SIM_COMMAND attach welds the plank to the gripper at their current relative pose: lifting
    the gripper 5 cm lifts the plank with it; after detach the gripper leaves it behind."""
    scene = str(robots.MODELS_DIR / "scenes" / "talos_plank.xml")
    with run_controller(
        "--robot", "talos", "--scene", scene, "--speed", "0", "--camera-rate", "0"
    ) as c:
        c.send_spec(stack(1, gripper=True))
        c.wait(lambda c: c.status.active_controller_id == 1, 30, "the controller")
        c.wait_time(0.5)
        q = configuration_from_state(talos[0], c.state)
        gripper0 = frame_pose(talos, q, "gripper_right_base_link")
        plank0 = c.object_pose("plank")
        c.attach("grasp/talos/right_gripper/plank")

        def lift(dz: float, start_us: int) -> None:
            s = np.linspace(0.0, 1.0, 1000)
            blend = 10 * s**3 - 15 * s**4 + 6 * s**5
            values = [
                pose_to_vector(pin.SE3(gripper0.rotation, gripper0.translation + [0, 0, dz * b]))
                for b in blend
            ]
            c.send_reference(reference_chunk(1, "right_gripper", start_us, values, last=True))

        lift(0.05, c.utime() + 20_000)
        c.wait_time(2.0)
        plank1 = c.object_pose("plank")
        gripper1 = frame_pose(
            talos, configuration_from_state(talos[0], c.state), "gripper_right_base_link"
        )
        assert gripper1.translation[2] - gripper0.translation[2] > 0.04, (
            c.status.mode,
            c.status.mode_reason,
            c.status.last_rejection,
            dict(zip(c.status.task_name, c.status.task_error_norm)),
        )
        # The plank kept its pose relative to the gripper.
        before, after = gripper0.actInv(plank0), gripper1.actInv(plank1)
        assert np.linalg.norm(after.translation - before.translation) < 0.005
        assert np.linalg.norm(pin.log3(before.rotation.T @ after.rotation)) < np.radians(1.0)
        # So it rose where the rigid grasp puts it (the weld holds at the current relative pose,
        # here about 0.5 m from the gripper frame: a 1° tilt of the hand moves it by 1 cm).
        carried = gripper1.act(before)
        assert plank1.translation[2] - plank0.translation[2] > 0.03
        assert abs(plank1.translation[2] - carried.translation[2]) < 0.005
        # Released, then the gripper goes back down 5 cm: the plank is left behind (it falls back
        # onto the table, at most to where it started).
        c.detach("grasp/talos/right_gripper/plank")
        c.wait_time(1.0)
        plank2 = c.object_pose("plank")
        assert plank2.translation[2] < plank1.translation[2] - 0.03
        assert c.status.num_rejected == 0
