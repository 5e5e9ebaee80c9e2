"""The dry run's rank check along a whole step: a step that starts and ends regular and crosses
the UR10's elbow singularity (arm stretched, elbow_joint = 0) is refused at the crossing, which
the start-only check misses; the factory's 6-DoF arm level (gripper and posture stacked, the
finger left to the gripper admittance) is not. The reference is independent of the code under
test: the frame's Jacobian by central differences of its forward kinematics (log6), its
singular values by numpy."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest

from marionette import robots
from marionette.control.spec import ControllerSpec, TaskSpec
from marionette.execution.dry_run import DryRunOptions, step_conditioning
from marionette.execution.factory import level_conditioning

ARM = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint")
ARM += ("wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
FRAME = "gripper_link"


@pytest.fixture(scope="module")
def ur10() -> pin.Model:
    model, _ = robots.load_pinocchio("ur10", with_collision=False)
    return model


def fd_jacobian(model: pin.Model, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """LOCAL Jacobian of FRAME: log6(M(q - h e_i)^-1 M(q + h e_i)) / 2h."""
    data, fid = model.createData(), model.getFrameId(FRAME)

    def pose(x):
        pin.framesForwardKinematics(model, data, x)
        return data.oMf[fid].copy()

    J = np.zeros((6, model.nv))
    for i in range(model.nv):
        e = np.zeros(model.nv)
        e[i] = h
        J[:, i] = pin.log6(pose(q - e).inverse() * pose(q + e)).vector / (2 * h)
    return J


def configuration(model: pin.Model, **joints: float) -> np.ndarray:
    q = pin.neutral(model)
    for name, value in joints.items():
        q[model.joints[model.getJointId(name)].idx_q] = value
    return q


def straight_path(qa: np.ndarray, qb: np.ndarray, duration: float = 1.0, dt: float = 1e-3):
    t = np.arange(round(duration / dt) + 1) * dt
    q = qa + (t / duration)[:, None] * (qb - qa)
    return SimpleNamespace(q=q, t=t, dt=dt, references={})


GENERIC = dict(shoulder_lift_joint=-1.2, wrist_1_joint=-1.0, wrist_2_joint=1.3, wrist_3_joint=0.4)


@pytest.mark.parametrize("elbow", [(0.7, -0.5), (-0.9, 0.3), (0.25, -0.35)])
def test_a_step_crossing_the_elbow_singularity_is_found_along_it(ur10, elbow):
    spec = ControllerSpec(1, "s", [TaskSpec("gripper", "se3", 0, frame=FRAME)])
    qa = configuration(ur10, elbow_joint=elbow[0], **GENERIC)
    qb = configuration(ur10, elbow_joint=elbow[1], **GENERIC)
    traj = straight_path(qa, qb)
    threshold = DryRunOptions().singular_threshold
    arm = [ur10.joints[ur10.getJointId(n)].idx_v for n in ARM]
    data = ur10.createData()
    for q in (qa, qb):  # regular at both ends: a start-only check passes it
        reference = np.linalg.svd(fd_jacobian(ur10, q)[:, arm], compute_uv=False)[-1]
        (level,) = level_conditioning(ur10, data, spec, q)
        assert level.rank == 6 and level.sigma_min > threshold
        # the finger column is zero in the 6x7 Jacobian: the sixth singular value is the arm's
        assert level.sigma_min == pytest.approx(reference, rel=1e-5)
    sigma, where = step_conditioning(ur10, spec, traj, DryRunOptions().sample_period_s)
    assert sigma < threshold
    # where the reference says: at elbow_joint = 0 (sampled within the 50 ms grid)
    t_cross = elbow[0] / (elbow[0] - elbow[1])
    t_found = float(where.rsplit("t = ", 1)[1].split()[0])
    assert abs(t_found - t_cross) <= 0.05 / 2 + 1e-9, (where, t_cross)
    k = int(np.argmin(np.abs(traj.t - t_found)))
    reference = np.linalg.svd(fd_jacobian(ur10, traj.q[k])[:, arm], compute_uv=False)[-1]
    assert sigma == pytest.approx(reference, rel=1e-4, abs=1e-8)


def test_the_stacked_arm_level_with_a_finger_left_to_the_admittance_is_regular(ur10):
    """The factory's level on a 6-DoF arm: gripper, gripper admittance and a posture of the six
    arm joints, one priority. finger_joint is in no row of the level; the level needs the six
    DoF its rows move, so its smallest singular value is that of [J_arm; I_6] — never 0."""
    spec = ControllerSpec(
        1,
        "s",
        [
            TaskSpec("gripper", "se3", 0, frame=FRAME, streamed=True),
            TaskSpec("gripper_admittance", "gripper_admittance", 0, joints=["finger_joint"]),
            TaskSpec("posture", "posture", 0, streamed=True, joints=list(ARM)),
        ],
    )
    arm = [ur10.joints[ur10.getJointId(n)].idx_v for n in ARM]
    qa = configuration(ur10, elbow_joint=0.6, **GENERIC)
    qb = configuration(ur10, elbow_joint=-0.6, **GENERIC)  # even across the elbow singularity
    traj = straight_path(qa, qb)
    sigma, _ = step_conditioning(ur10, spec, traj, 0.05)
    references = [
        np.linalg.svd(np.vstack([fd_jacobian(ur10, q)[:, arm], np.eye(6)]), compute_uv=False)[-1]
        for q in traj.q[::50]
    ]
    assert sigma == pytest.approx(min(references), rel=1e-4)
    assert sigma >= 1.0 - 1e-9  # [J; I] has singular values sqrt(1 + s_J^2) >= 1
