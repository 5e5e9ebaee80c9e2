"""The static load a plan puts on the robot's actuators: each joint's gravity torque — its own
links and the objects its grippers carry — against the joint's effort limit, along a step's
planned configurations.

A joint near its limit in static gravity has nothing left for the motion, a tracking error or a
push: its servo saturates and the hand it carries sags (TALOS' right wrist, a 3 N·m actuator,
carries the plank at 0.86–0.90 of its limit in the plank flip's plans). The torque at rest is
τ = g(q) − J_Gᵀ W per carried object: Pinocchio's RNEA with zero velocity and acceleration for the
links, and each object's weight W (at its centre of mass) on the gripper that alone holds it. An
object two grippers hold is left out (how its weight splits is the controller's choice), and so
are the joints that carry a contact body — a humanoid's legs, whose load depends on how the
ground shares the weight between the feet: only the joints below which no contact body hangs are
judged (arms, torso, head; every joint of a fixed-base arm).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
import pinocchio as pin

from marionette import robots
from marionette.execution.plan_steps import PlanRobotMap, Step


@dataclass(frozen=True)
class StaticLoad:
    """The largest ``ratio`` |τ| / effort limit over a step's samples and judged joints, the
    ``joint`` and the plan sample where it is reached."""

    ratio: float
    joint: str
    sample: int


@dataclass(frozen=True)
class Carried:
    """An object's weight on a gripper: the gripper's frame in the robot model, the object's
    mass [kg] and centre of mass [m] in the object frame."""

    frame: int
    mass: float
    com: np.ndarray


def judged_joints(model: pin.Model, contact_frames: list[str]) -> list[int]:
    """The 1-DoF joints with an effort limit below which no contact body hangs."""
    contact_joints = {
        model.frames[model.getFrameId(f)].parentJoint for f in contact_frames if model.existFrame(f)
    }
    out = []
    for j in range(1, model.njoints):
        if model.joints[j].nv != 1 or model.effortLimit[model.joints[j].idx_v] <= 0:
            continue
        if contact_joints & set(model.subtrees[j]):
            continue
        out.append(j)
    return out


def static_torques(
    model: pin.Model,
    data: pin.Data,
    q: np.ndarray,
    carried: list[tuple[Carried, pin.SE3]],
) -> np.ndarray:
    """τ (nv) at rest at ``q``: the links' gravity and each (object, its world pose) of
    ``carried`` hanging on its gripper, both under the model's gravity."""
    tau = pin.rnea(model, data, q, np.zeros(model.nv), np.zeros(model.nv)).copy()
    if carried:
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
    for c, X_WO in carried:
        F = c.mass * np.asarray(model.gravity.linear)
        p = data.oMf[c.frame].translation
        wrench = np.concatenate([F, np.cross(X_WO.act(c.com) - p, F)])
        J = pin.getFrameJacobian(model, data, c.frame, pin.LOCAL_WORLD_ALIGNED)
        tau -= J.T @ wrench
    return tau


def step_static_load(
    model: pin.Model,
    robot_map: PlanRobotMap,
    step: Step,
    gripper_frames: dict[str, str],
    contact_frames: list[str],
    every: int = 5,
) -> StaticLoad | None:
    """The largest static load of ``step`` (every ``every``-th plan sample and its last); None
    when no joint is judged. ``gripper_frames``: gripper name -> its frame in ``model``."""
    joints = judged_joints(model, contact_frames)
    if not joints:
        return None
    holders: dict[str, list[str]] = {}
    for gripper, handle in step.grasps.items():
        holders.setdefault(handle.split("/")[0], []).append(gripper)
    alone = {
        obj: Carried(model.getFrameId(gripper_frames[g[0]]), *_inertia(obj))
        for obj, g in holders.items()
        if len(g) == 1 and g[0] in gripper_frames and obj in robot_map.objects
    }
    data = model.createData()
    limit = np.array([model.effortLimit[model.joints[j].idx_v] for j in joints])
    rows = [model.joints[j].idx_v for j in joints]
    worst = StaticLoad(0.0, "", 0)
    for k in sorted({*range(0, len(step.q), every), len(step.q) - 1}):
        q_plan = step.q[k]
        carried = [(c, robot_map.object_pose(q_plan, obj)) for obj, c in alone.items()]
        tau = static_torques(model, data, robot_map.robot_q(q_plan), carried)
        ratio = np.abs(tau[rows]) / limit
        i = int(np.argmax(ratio))
        if ratio[i] > worst.ratio:
            worst = StaticLoad(float(ratio[i]), model.names[joints[i]], k)
    return worst


@cache
def _inertia(obj: str) -> tuple[float, np.ndarray]:
    """An object's mass [kg] and centre of mass in its frame [m] (its model's root body)."""
    model: pin.Model = robots.load_object(obj).model
    inertia = model.inertias[1]
    return float(inertia.mass), np.array(inertia.lever)
