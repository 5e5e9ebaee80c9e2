"""Task errors split by physical unit, one panel per unit (thesis 000 fig. 5.4: position and
orientation apart), every axis labelled with its unit.

The controller reports one norm ‖e‖ per task (CONTROLLER_STATUS). Its unit follows the task's kind
(:mod:`marionette.control.spec`):

================================  =========================================================
kind                              panel
================================  =========================================================
se3, relative_se3                 position [mm] and orientation [deg], recomputed: forward
                                  kinematics (Pinocchio) of the recorded robot state against
                                  the task's reference (streamed, fixed or held), E = X_D⁻¹ X_F,
                                  position ‖E.t‖ and angle ‖log3(E.R)‖ over the task's mask
position, com                     position [mm] (the norm itself, metres)
posture                           joint [rad]
gripper_admittance                gripper [rad]: q − r while positioning, K_a (f̂ − f*) / λ
                                  while holding a force (the grip force in N has its own plot)
gaze                              image point [normalised image coordinates X/Z, Y/Z]
se3 / pbvs without a known        pose ‖log6 e‖, labelled as mixing m and rad (a pbvs task's
reference (walk, visual servo)    reference is corrected by vision at run time)
================================  =========================================================

The recomputed pose errors are those of the *measured* robot (ROBOT_STATE: the joints the
simulator or the hardware reached), named "<task> (measured)": they include what the controller's
own error does not see, such as joint servos sagging under gravity (the controller tracks its own
integrated configuration; its ‖e‖ per task stays in report.json). The other series are the
controller's ‖e‖. A "held" reference (a fixed task with no reference) is the task's pose in the
first recorded state at or after the controller switch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from marionette.control.spec import TaskSpec

POSITION = "position error [mm]"
ORIENTATION = "orientation error [deg]"
JOINT = "joint error [rad]"
GRIPPER = "gripper: q − r, or\nK_a (f̂ − f*)/λ holding [rad]"
IMAGE = "gaze: image point error [normalised, X/Z]"
MIXED = "pose ‖log6 e‖, no reference\n[m and rad mixed]"
UNKNOWN = "task error ‖e‖, kind unknown [task's unit]"
PANELS = (POSITION, ORIENTATION, JOINT, GRIPPER, IMAGE, MIXED, UNKNOWN)

_NORM_PANEL = {  # kinds whose reported norm has a single unit: (panel, factor to that unit)
    "position": (POSITION, 1e3),
    "com": (POSITION, 1e3),
    "posture": (JOINT, 1.0),
    "gripper_admittance": (GRIPPER, 1.0),
    "gaze": (IMAGE, 1.0),
}
_POSES = ("se3", "relative_se3")
MEASURED = " (measured)"  # suffix of the series recomputed from the recorded robot state
MAX_SAMPLES_PER_STEP = 1500  # forward kinematics on at most this many recorded states per step


@dataclass
class StepTasks:
    """One controller of a run as the plot needs it: ``trace`` the CONTROLLER_STATUS norms
    [(utime [us], {task: ‖e‖})], ``tasks`` its task specs by name, ``references`` the references
    its streamed tasks followed, by task name: (t (N,) [s controller time], values (N x k),
    poses as x y z qw qx qy qz)."""

    trace: list[tuple[int, dict[str, float]]]
    tasks: dict[str, TaskSpec] = field(default_factory=dict)
    references: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


# panel -> series (the task's name, + MEASURED when recomputed) -> segments (t [s], error in the
# panel's unit), one per step
Panels = dict[str, dict[str, list[tuple[np.ndarray, np.ndarray]]]]


def configuration_units(model: pin.Model) -> list[str]:
    """The unit of each coordinate of q (nq): "m" (prismatic, translations), "rad" (revolute),
    "-" (quaternion and cos/sin coordinates)."""
    out: list[str] = []
    for j in range(1, model.njoints):
        kind = model.joints[j].shortname().removeprefix("JointModel")
        if kind.startswith(("PX", "PY", "PZ", "Prismatic", "Translation")):
            out += ["m"] * model.joints[j].nq
        elif kind == "FreeFlyer":
            out += ["m"] * 3 + ["-"] * 4
        elif kind == "Planar":
            out += ["m"] * 2 + ["-"] * 2
        elif kind.startswith(("RUB", "Spherical")) or model.joints[j].nq != 1:
            out += ["-"] * model.joints[j].nq
        else:
            out += ["rad"]
    return out


def pose(row: Any) -> pin.SE3:
    """An SE3 from a reference row (x y z qw qx qy qz)."""
    x, y, z, qw, qx, qy, qz = (float(v) for v in row)
    quat = pin.Quaternion(qw, qx, qy, qz)
    quat.normalize()
    return pin.SE3(quat.matrix(), np.array([x, y, z]))


def pose_error(X_ref: pin.SE3, X: pin.SE3, mask: Any = ()) -> tuple[float, float]:
    """(position [m], angle [rad]) of E = X_ref⁻¹ X over the mask's components (x y z rx ry rz,
    empty = all): ‖E.translation[sel]‖ and ‖log3(E.rotation)[sel]‖."""
    E = X_ref.actInv(X)
    sel = _mask6(mask)
    return (
        float(np.linalg.norm(E.translation[sel[:3]])),
        float(np.linalg.norm(pin.log3(E.rotation)[sel[3:]])),
    )


def _mask6(mask: Any) -> np.ndarray:
    """The 6 selected components (x y z rx ry rz) of a task mask (none selected = all), as the
    controller reads it."""
    sel = np.array([bool(m) for m in mask] + [False] * (6 - len(mask)))
    return sel if sel.any() else np.ones(6, dtype=bool)


def _frame_pose(model: pin.Model, data: pin.Data, task: TaskSpec) -> pin.SE3:
    """The task's controlled pose in the last forward kinematics of ``data`` (a copy)."""
    X_WA = data.oMf[model.getFrameId(task.frame)]
    if task.kind == "relative_se3":
        return data.oMf[model.getFrameId(task.frame_b)].actInv(X_WA)
    return X_WA.copy()


def _reference_poses(
    task: TaskSpec,
    references: dict[str, tuple[np.ndarray, np.ndarray]],
    t: np.ndarray,
    held: pin.SE3,
) -> list[pin.SE3] | None:
    """The reference of a pose task at the times ``t``: its streamed samples (nearest, clamped
    to the ends), its fixed reference, or ``held``; None when unknown here."""
    if task.reference_channel:  # the walk's pattern generator, inside the controller
        return None
    if task.streamed:
        if task.name not in references:
            return None
        t_ref, rows = references[task.name]
        k = np.clip(np.searchsorted(t_ref, t), 0, len(t_ref) - 1)
        return [pose(rows[i]) for i in k]
    if len(task.reference) == 7:
        return [pose(task.reference)] * len(t)
    return [held] * len(t)


def split_by_unit(
    steps: list[StepTasks], model: pin.Model, t_rec: np.ndarray, q_rec: np.ndarray
) -> Panels:
    """The errors of every task of every step in the panel of their unit (see the module).
    ``t_rec`` (M,) [s] and ``q_rec`` (M x nq): the recorded robot states."""
    panels: Panels = {p: {} for p in PANELS}
    data = model.createData()
    for step in steps:
        if not step.trace:
            continue
        t = np.array([u for u, _ in step.trace]) * 1e-6
        names = list(dict.fromkeys(n for _, errs in step.trace for n in errs))
        in_step = np.flatnonzero((t_rec >= t[0]) & (t_rec <= t[-1]))
        in_step = in_step[:: max(1, len(in_step) // MAX_SAMPLES_PER_STEP)]
        for name in names:
            e = np.array([errs.get(name, np.nan) for _, errs in step.trace])
            task = step.tasks.get(name)
            if task is not None and task.kind in _POSES and len(in_step):
                split = _split_pose(task, step, model, data, t_rec[in_step], q_rec[in_step])
                if split is not None:
                    (tp, ep), (to, eo) = split
                    if ep is not None:
                        panels[POSITION].setdefault(name + MEASURED, []).append((tp, ep * 1e3))
                    if eo is not None:
                        panels[ORIENTATION].setdefault(name + MEASURED, []).append(
                            (to, np.degrees(eo))
                        )
                    continue
            if task is None:
                panel, factor = UNKNOWN, 1.0
            else:
                panel, factor = _NORM_PANEL.get(task.kind, (MIXED, 1.0))
            panels[panel].setdefault(name, []).append((t, e * factor))
    return {p: series for p, series in panels.items() if series}


def _split_pose(
    task: TaskSpec,
    step: StepTasks,
    model: pin.Model,
    data: pin.Data,
    t: np.ndarray,
    q: np.ndarray,
) -> tuple[tuple[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]] | None:
    """(t, position [m]) and (t, angle [rad]) of a pose task from the recorded states, a part
    None when the mask leaves it out; None when the reference is not known here."""
    if not model.existFrame(task.frame) or (
        task.kind == "relative_se3" and not model.existFrame(task.frame_b)
    ):
        return None
    poses = []
    for qk in q:
        pin.framesForwardKinematics(model, data, qk)
        poses.append(_frame_pose(model, data, task))
    refs = _reference_poses(task, step.references, t, poses[0])
    if refs is None:
        return None
    errors = np.array([pose_error(R, X, task.mask) for R, X in zip(refs, poses)])
    mask = _mask6(task.mask)
    return (
        (t, errors[:, 0] if any(mask[:3]) else None),
        (t, errors[:, 1] if any(mask[3:]) else None),
    )


def plot_task_errors(panels: Panels, switches: list[float], title: str) -> Any:
    """One log-scale panel per unit, stacked, a task in the same colour everywhere, grey lines
    at the controller switches ``switches`` [s]; returns the matplotlib figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [p for p in PANELS if p in panels] or [POSITION]
    fig, axes = plt.subplots(
        len(shown), 1, figsize=(11, 1.2 + 2.6 * len(shown)), sharex=True, squeeze=False
    )
    colours: dict[str, Any] = {}
    for ax, panel in zip(axes[:, 0], shown):
        for name, segments in panels.get(panel, {}).items():
            for k, (t, e) in enumerate(segments):
                kw: dict[str, Any] = {"label": name} if k == 0 else {}
                if name in colours:
                    kw["color"] = colours[name]
                (line,) = ax.semilogy(t, np.maximum(e, 1e-7), lw=1, **kw)
                colours.setdefault(name, line.get_color())
        for s in switches:
            ax.axvline(s, color="0.85", lw=0.8)
        ax.set_ylabel(panel, fontsize=8)
        ax.set_xlabel("controller time [s]")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, ncol=4)
    axes[0, 0].set_title(title)
    return fig
