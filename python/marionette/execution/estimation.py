"""Estimation of the initial state (thesis 000 §3.2.2, fig. 3.5): the configuration measured by
the robot's encoders and the object poses (:func:`sensed_object_poses`: perception) never
satisfies the constraints of any graph state exactly; project it onto every main state of the
constraint graph (Newton-Raphson, Algorithm 1) and keep the state with the smallest projection
distance |q_projected ⊖ q_measured|. Then find where the plan stands: the step whose start (its
graph state, the object poses, then the robot configuration) is nearest to the projected
configuration, so that steps already done are skipped (§3.2.2: "detect when the system is
already in a later step of the process").
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import channels, lcmt_object_poses
from marionette.execution.monitor import pose_from_message
from marionette.execution.plan_steps import PlanRobotMap, Step

OBJECT_TOLERANCE = 0.01  # [m + rad] object poses this close are "the same situation"


def sensed_object_poses(
    client: Any,
    objects: Iterable[str],
    look_s: float,
    log: Callable[[str], None],
) -> dict[str, pin.SE3]:
    """The poses of ``objects`` as the robot senses them before it moves: the camera's latest
    estimate of each (OBJECT_POSES, ``marionette perceive``) seen within ``look_s`` of the
    controller's time from now; ``look_s`` 0: the robot has no object sensor. An object not
    sensed is left out, with one line saying so: :func:`measured_configuration` then keeps it
    where the plan starts it, which is what the robot believes. ``client``: a
    :class:`~marionette.control.client.ControllerClient`."""
    wanted = sorted(objects)
    if look_s <= 0:
        if wanted:
            log(f"estimation: no object sensor: {', '.join(wanted)} at the plan's initial pose")
        return {}
    seen: dict[str, pin.SE3] = {}  # written by the bus thread, read under the client's wait
    lock = threading.Lock()

    def on_poses(msg: Any) -> None:
        with lock:
            seen.update(
                (o.object_name, pose_from_message(o))
                for o in msg.objects
                if o.object_name in wanted
            )

    subscription = client.bus.subscribe(channels.OBJECT_POSES, lcmt_object_poses, on_poses)
    end = client.utime() + int(look_s * 1e6)
    try:
        client.wait(
            lambda c: c.utime() >= end or len(seen) == len(wanted),
            10.0 + 5.0 * look_s,
            f"{look_s} s of controller time for the camera's first estimates",
        )
    finally:
        client.bus.lcm.unsubscribe(subscription)
    with lock:
        found = dict(seen)
    unseen = [n for n in wanted if n not in found]
    if unseen:
        log(
            f"estimation: {', '.join(unseen)} not seen by the camera within {look_s:g} s: at the "
            "plan's initial pose"
        )
    return found


@dataclass
class StateEstimate:
    """``state``: nearest graph state; ``residual``: |q_projected ⊖ q_measured| (velocity-space
    norm, m and rad mixed); ``ranking``: every main state with its residual (None when the
    projection failed), best first."""

    state: str
    residual: float
    q_measured: np.ndarray
    q_projected: np.ndarray
    ranking: list[tuple[str, float | None]]


def measured_configuration(
    q_template: np.ndarray,
    robot_map: PlanRobotMap,
    q_robot: np.ndarray,
    object_poses: dict[str, pin.SE3],
) -> np.ndarray:
    """A plan configuration (nq_plan) from the robot's measured configuration and the measured
    object poses; objects not measured keep their value in ``q_template``."""
    q = np.array(q_template, dtype=float)
    q[robot_map.idx] = q_robot
    for name, X in object_poses.items():
        if name in robot_map.objects:
            q[robot_map.objects[name]] = pin.SE3ToXYZQUAT(X)
    return q


def estimate_state(graph, q_measured: np.ndarray) -> StateEstimate:
    """Projects ``q_measured`` onto every main state of ``graph`` (a planning ConstraintGraph)."""
    model = graph.problem.model
    projected: list[tuple[str, float, np.ndarray]] = []  # (state, residual, q_projected)
    failed: list[str] = []
    for state in graph.main_states():
        q = np.array(q_measured, dtype=float)
        if state.project(q).success:
            projected.append(
                (state.name, float(np.linalg.norm(pin.difference(model, q_measured, q))), q)
            )
        else:
            failed.append(state.name)
    ok = sorted(projected, key=lambda r: r[1])
    if not ok:
        raise RuntimeError("the measured configuration projects onto no state of the graph")
    ranking: list[tuple[str, float | None]] = [(n, r) for n, r, _ in ok]
    ranking += [(n, None) for n in failed]
    name, residual, q_proj = ok[0]
    return StateEstimate(name, residual, np.asarray(q_measured, dtype=float), q_proj, ranking)


def _object_distance(robot_map: PlanRobotMap, qa: np.ndarray, qb: np.ndarray) -> float:
    d = 0.0
    for name in robot_map.objects:
        err = pin.log6(
            robot_map.object_pose(qa, name).actInv(robot_map.object_pose(qb, name))
        ).vector
        d += float(np.linalg.norm(err))
    return d


def first_step_to_run(steps: list[Step], robot_map: PlanRobotMap, estimate: StateEstimate) -> int:
    """Index of the step to start from (``len(steps)``: the goal is already reached).

    Candidates are the steps starting in the estimated state (or a state equally near), and
    the plan's end; among those
    whose objects are within :data:`OBJECT_TOLERANCE` of the best match, the one whose start
    robot configuration is nearest wins (the earliest on ties)."""
    q = estimate.q_projected
    model = robot_map.model
    # States the configuration is in (an intersection, e.g. grasped and placed, is in two).
    states = {None} | {
        n for n, r in estimate.ranking if r is not None and r <= estimate.residual + 0.01
    }
    candidates: list[tuple[int, np.ndarray]] = [
        (s.index, s.q[0]) for s in steps if s.start_state in states
    ]
    if steps and steps[-1].end_state in states:
        candidates.append((len(steps), steps[-1].q[-1]))
    if not candidates:
        return 0
    d_obj = [_object_distance(robot_map, q, qs) for _, qs in candidates]
    best = min(d_obj)
    near = [(i, qs) for (i, qs), d in zip(candidates, d_obj) if d <= best + OBJECT_TOLERANCE]
    d_robot = [
        float(np.linalg.norm(pin.difference(model, robot_map.robot_q(q), robot_map.robot_q(qs))))
        for _, qs in near
    ]
    return near[int(np.argmin(d_robot))][0]
