"""Walking with marionette-controller: the walking controller spec and the balance measures a
walk is judged by (measured ZMP against the support polygon of the loaded soles, Dang 2012
§2.4 fig. 2.16; footstep plans merged the way the controller's footstep manager applies them).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import ConvexHull

from marionette.control.spec import ControllerSpec, TaskSpec

FEET = ("left", "right")
LOADED_FORCE_N = 10.0  # a sole carries load above this normal force [N]


def walking_spec(
    robot: str,
    controller_id: int = 1,
    name: str = "walk",
    head_pitch: float | None = None,
    gaze: tuple[float, float, float] | None = None,
) -> ControllerSpec:
    """The walking stack of ``robot`` (its robot.yaml feet, left then right, and its root link
    as the waist): feet (20/s) and CoM (5/s) from the controller's pattern generator and the
    waist turning with the feet's mean yaw, as it stood at the start (walk:waist; 20/s) at
    level 0, posture (2/s) at level 1. A CoM gain above ~5/s under-damps the sway in MuJoCo
    (tests/python/walk/test_controller_walk.py). With the waist's yaw left free (to the posture
    task), a long stride swung it 10° and the walk diverged laterally two steps later: 6 of 12
    step-over trials fell after the crossing, 2 of 12 with the waist's yaw held.

    ``head_pitch`` [rad]: the head looks down at the floor ahead while walking (its camera
    measures what lies on the path): the head joints robot.yaml's calibration names (pitch,
    yaw) are held at (``head_pitch``, 0) at level 1, the posture moves to level 2.

    ``gaze`` (a world point): the head camera keeps that point at the image centre instead — a
    ``gaze`` task named "gaze", streamed (:class:`~marionette.scenarios.walking_scenario.
    GazeFollower` moves the point as the camera sees the object move), at level 2, below the
    posture of every other joint at level 1: only the head turns to look (:func:`_gaze_tasks`).
    The posture of all joints stays, at level 3."""
    from marionette import robots

    desc = robots.robot(robot)
    feet = {f.name: f.frame for f in desc.feet}
    if set(feet) != set(FEET):
        raise ValueError(f"{desc.semantics}: walking needs two feet named left and right")
    head: list[TaskSpec] = []
    if head_pitch is not None:
        if len(desc.calibration_head_joints) != 2:
            raise ValueError(
                f"{desc.semantics}: looking down while walking needs the head's pitch and yaw "
                "joints (calibration: head_joints)"
            )
        model, _ = robots.load_pinocchio(robot, with_collision=False)
        q = robots.reference_configuration(robot, model)
        pitch, yaw = (model.joints[model.getJointId(j)].idx_q for j in desc.calibration_head_joints)
        q[pitch], q[yaw] = float(head_pitch), 0.0
        head = [
            TaskSpec(
                "head",
                "posture",
                1,
                gain=2.0,
                joints=desc.calibration_head_joints,
                reference=tuple(float(v) for v in q),
            )
        ]
    if gaze is not None:
        if head_pitch is not None:
            raise ValueError("walking_spec: give head_pitch or gaze, not both")
        head = _gaze_tasks(robot, gaze)
    return ControllerSpec(
        controller_id,
        name,
        [
            *(
                TaskSpec(
                    f"{side}_foot",
                    "se3",
                    0,
                    frame=feet[side],
                    gain=20.0,
                    reference_channel=f"walk:{side}_foot",
                )
                for side in FEET
            ),
            TaskSpec("com", "com", 0, gain=5.0, reference_channel="walk:com"),
            TaskSpec(
                "waist",
                "se3",
                0,
                frame=robots.root_link(robot),
                mask=(False, False, False, True, True, True),
                gain=20.0,
                reference_channel="walk:waist",
            ),
            *head,
            TaskSpec("posture", "posture", 1 + len(head), gain=2.0),
        ],
    )


def _gaze_tasks(robot: str, point: tuple[float, float, float]) -> list[TaskSpec]:
    """:func:`walking_spec`'s gaze: the posture of every 1-DoF joint but the head's and the legs'
    (those the feet hang from) held at level 1, the camera on ``point`` at level 2: the legs walk
    (level 0 decides them), the head looks, nothing else moves for it.

    Measured: with only the torso held, a gaze whose head joint had reached its limit lowered the
    camera by bending the legs, the arms swinging to keep the CoM: the base sank 12 cm and the
    robot fell. With the legs held too, level 0 could only correct the CoM through the head (its
    mass moves the CoM a little): the walking stack's first command jumped 0.5 rad/s and was
    refused."""
    from marionette import robots

    desc = robots.robot(robot)
    if desc.camera_frame is None or len(desc.calibration_head_joints) != 2:
        raise ValueError(
            f"{desc.semantics}: looking at a point while walking needs a camera frame and the "
            "head's pitch and yaw joints (calibration: head_joints)"
        )
    model, _ = robots.load_pinocchio(robot, with_collision=False)
    legs = {
        j
        for f in desc.feet
        for j in model.supports[model.frames[model.getFrameId(f.frame)].parentJoint]
    }
    body = [
        model.names[j]
        for j in range(1, model.njoints)
        if model.joints[j].nv == 1
        and j not in legs
        and model.names[j] not in desc.calibration_head_joints
    ]
    return [
        TaskSpec("upper_body", "posture", 1, gain=2.0, joints=tuple(body)),
        TaskSpec(
            "gaze",
            "gaze",
            2,
            frame=desc.camera_frame,
            gain=2.0,
            reference=tuple(float(v) for v in point),
            streamed=True,
        ),
    ]


@lru_cache(maxsize=4)
def sole_half_size(mjcf: Path, geom: str = "left_sole") -> tuple[float, float]:
    """Half length and half width [m] of the sole contact box ``geom`` of a robot MJCF (the
    surface MuJoCo's contacts use, hence the support polygon's)."""
    for g in ET.parse(mjcf).getroot().iter("geom"):
        if g.get("name") == geom:
            size = [float(v) for v in g.get("size", "").split()]
            if g.get("type") != "box" or len(size) != 3:
                raise ValueError(f"{mjcf}: geom {geom!r} is not a box with 3 half sizes")
            return size[0], size[1]
    raise ValueError(f"{mjcf}: no geom named {geom!r}")


def sole_corners(foot, half: tuple[float, float]) -> np.ndarray:
    """(4, 2) corners in world of a sole at ``foot`` = (x, y, z, yaw) with half sizes ``half``."""
    x, y, _, yaw = (float(v) for v in foot)
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[a * half[0], b * half[1]] for a in (-1, 1) for b in (-1, 1)])
    return np.array([x, y]) + local @ np.array([[c, s], [-s, c]])


def polygon_margin(point, corners: np.ndarray) -> float:
    """Signed distance [m] of the 2D ``point`` inside the convex hull of ``corners`` (> 0 inside):
    the smallest distance to a facet, each facet being normal . x + offset <= 0 inside."""
    hull = ConvexHull(np.asarray(corners, dtype=float))
    return float(
        -np.max(hull.equations[:, :2] @ np.asarray(point, dtype=float) + hull.equations[:, 2])
    )


def zmp_margins(
    statuses, loaded_feet: dict[int, list[str]], half: tuple[float, float]
) -> np.ndarray:
    """(n, 2) rows (utime [s], margin [m]) of the measured ZMP of each WALK_STATUS inside the
    polygon of the soles that carry load at the same tick (``loaded_feet``: utime -> sides).
    Sole poses are the walk's current soles (its references, within a few mm of the real ones).
    Statuses without a state of the same tick, without a loaded sole or a finite ZMP are skipped."""
    rows = []
    for s in statuses:
        feet = loaded_feet.get(s.utime)
        if not feet or not np.all(np.isfinite(s.zmp_measured)):
            continue
        corners = np.vstack(
            [sole_corners(s.left_foot if side == "left" else s.right_foot, half) for side in feet]
        )
        rows.append((s.utime * 1e-6, polygon_margin(s.zmp_measured, corners)))
    return np.array(rows).reshape(-1, 2)


def loaded_soles(state) -> list[str]:
    """Sides whose sole carries more than LOADED_FORCE_N in an lcmt_robot_state."""
    fz = {name: w[2] for name, w in zip(state.contact_frame, state.contact_wrench)}
    return [side for side in FEET if fz.get(f"{side}_sole_link", 0.0) > LOADED_FORCE_N]


class MergedPlan:
    """The footsteps the controller executes: each FOOTSTEP_PLAN replaces the steps from its
    ``first_step_index`` on, except a step that has started meanwhile (the footstep manager
    never changes a started step, Dang §2.6.3; FootstepManager::ApplyPlan)."""

    def __init__(self) -> None:
        self.steps: dict[int, Any] = {}  # global index -> lcmt_footstep

    def apply(self, plan, current_step: int) -> None:
        """``current_step``: WALK_STATUS.current_step_index when the plan arrived (-1 standing)."""
        if not self.steps:
            self.steps = {int(s.index): s for s in plan.steps}
            return
        first = max(int(plan.first_step_index), int(current_step) + 1)
        self.steps = {i: s for i, s in self.steps.items() if i < first}
        for s in plan.steps:
            if s.index >= first:
                self.steps[int(s.index)] = s

    def final_stance(self, start: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Last sole (x, y, z, yaw) of each side, ``start`` for a side that never steps."""
        out = {side: np.asarray(start[side], dtype=float) for side in FEET}
        for i in sorted(self.steps):
            s = self.steps[i]
            out["left" if s.is_left else "right"] = np.array([s.x, s.y, s.z, s.yaw])
        return out

    def rows(self) -> list[tuple[int, bool, np.ndarray]]:
        return [
            (
                i,
                bool(self.steps[i].is_left),
                np.array([self.steps[i].x, self.steps[i].y, self.steps[i].z, self.steps[i].yaw]),
            )
            for i in sorted(self.steps)
        ]
