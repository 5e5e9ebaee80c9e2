"""The grip force a gripper holds, two ways (thesis 000 §3.2.4.3):

* **estimate** — what the ``gripper_admittance`` task regulates: the gripper joint's effort
  (ROBOT_STATE ``joint_effort``, MuJoCo's actuator force: the motor current's stand-in) through
  eq. 3.11–3.13, f̂ = s · k_τ k_gear · τ / d with the task's own parameters (s the closing
  direction, so f̂ > 0 squeezes);
* **contact** — the independent measurement: the MuJoCo contact forces (``mj_contactForce``) on
  the gripper's jaw bodies, which marionette-controller publishes in ROBOT_STATE after the soles
  (``contact_frame`` = the body name, wrench on the robot, world axes; RobotInfo::grip_bodies).
  A gripper's two jaws close along ±y of its frame (robot.yaml ``grippers[].jaws``, the +y jaw
  first): a squeezed object pushes the +y jaw along +y and the −y jaw along −y. The grip force is
  the mean of the two pushes, F = (F₊·y − F₋·y) / 2 (equal for an object the fingers alone hold; a
  grasp weld can take a share of either).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from marionette import channels, lcmt_robot_state
from marionette.control.client import configuration_from_state, vector_to_pose
from marionette.execution.force_event import (
    DEFAULT_LEVER_ARM,
    DEFAULT_TORQUE_PER_EFFORT,
    force_estimate,
)


@dataclass(frozen=True)
class GripperGeometry:
    """One gripper: its joint, the link carrying its frame and the frame's y axis in it (the
    closing axis), its jaw links and the estimate's constants."""

    joint: str
    base_link: str
    y_in_link: np.ndarray  # (3,) the gripper frame's y axis in base_link
    plus_jaw: tuple[str, ...]
    minus_jaw: tuple[str, ...]
    lever_arm: float  # d [m] of eq. 3.13 (the admittance task's `lever_arm`)
    closing_direction: float  # s: sign of q̇ when closing
    torque_per_effort: float = DEFAULT_TORQUE_PER_EFFORT

    @staticmethod
    def of(
        robot: str, gripper: str, parameters: dict[str, float], closing_direction: float
    ) -> GripperGeometry | None:
        """The geometry of ``robot``'s ``gripper`` (robot.yaml: its joint, frame and jaws) with
        the estimate of an admittance task with ``parameters``; None for a gripper without a
        joint or without declared jaws."""
        from marionette import robots

        g = robots.semantics(robot).gripper(gripper)
        jaws = robots.robot(robot).jaws.get(gripper)
        if g.joint is None or jaws is None:
            return None
        return GripperGeometry(
            g.joint,
            g.link,
            g.pose.se3().rotation[:, 1].copy(),
            jaws[0],
            jaws[1],
            parameters.get("lever_arm", DEFAULT_LEVER_ARM),
            closing_direction,
            parameters.get("torque_per_effort", DEFAULT_TORQUE_PER_EFFORT),
        )


def grip_forces(
    state: Any, model: pin.Model, data: pin.Data, g: GripperGeometry
) -> tuple[float, float, float]:
    """(estimate f̂ [N], contact grip force F [N], push of the +y jaw minus the -y jaw's [N]) of
    gripper ``g`` in one ``lcmt_robot_state``; NaN contact values when the state carries no jaw
    wrenches (kinematic backend)."""
    efforts = dict(zip(state.joint_name, state.joint_effort))
    estimate = force_estimate(
        efforts[g.joint], g.closing_direction, g.torque_per_effort, g.lever_arm
    )
    wrenches = dict(zip(state.contact_frame, state.contact_wrench))
    if not all(b in wrenches for b in g.plus_jaw + g.minus_jaw):
        return estimate, float("nan"), float("nan")
    q = configuration_from_state(model, state)
    pin.framesForwardKinematics(model, data, q)
    y_W = data.oMf[model.getFrameId(g.base_link)].rotation @ g.y_in_link  # closing axis, world
    push_plus = sum(float(np.dot(wrenches[b][:3], y_W)) for b in g.plus_jaw)
    push_minus = -sum(float(np.dot(wrenches[b][:3], y_W)) for b in g.minus_jaw)
    return estimate, 0.5 * (push_plus + push_minus), push_plus - push_minus


@dataclass
class GripForceRecorder:
    """Estimate and contact grip force of each gripper vs controller time, from ROBOT_STATE
    (every ``every``-th message), and, in a simulation, where each object is in each gripper's
    hand (its pose in the gripper's link, from SIM_OBJECT_POSES: the simulator's truth, to judge
    the grasp afterwards, never fed back). The LCM callbacks only keep the messages: the
    kinematics run after the run (:meth:`compute`), so the demo's bus thread, which also streams
    the references, is never slowed down by it."""

    model: pin.Model
    grippers: dict[str, GripperGeometry]
    every: int = 2
    t: list[float] = field(default_factory=list)  # [s] controller time
    estimate: dict[str, list[float]] = field(default_factory=dict)  # [N]
    contact: dict[str, list[float]] = field(default_factory=dict)  # [N]
    # gripper -> object -> (time [s], pose of the object in the gripper's link) samples
    in_hand: dict[str, dict[str, list[tuple[float, pin.SE3]]]] = field(default_factory=dict)
    _messages: list[Any] = field(default_factory=list)  # robot states
    # (robot state, object poses) of the same controller tick: the simulator publishes the
    # objects (a few Hz) right after the tick's state
    _in_hand: list[tuple[Any, Any]] = field(default_factory=list)
    _last_state: Any = None
    _count: int = 0

    def __post_init__(self) -> None:
        self._data = self.model.createData()
        for name in self.grippers:
            self.estimate[name], self.contact[name] = [], []
            self.in_hand[name] = {}

    def subscribe(self, bus: Any) -> GripForceRecorder:
        from marionette import lcmt_object_poses

        bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, self.on_state)
        bus.subscribe(channels.SIM_OBJECT_POSES, lcmt_object_poses, self.on_objects)
        return self

    def on_state(self, msg: Any) -> None:
        self._last_state = msg
        self._count += 1
        if self._count % self.every == 0:
            self._messages.append(msg)

    def on_objects(self, msg: Any) -> None:
        state = self._last_state
        if state is not None and state.utime == msg.utime:
            self._in_hand.append((state, msg))

    def compute(self) -> GripForceRecorder:
        """Turns the messages kept so far into the time series (t, estimate, contact, the
        objects' poses in the hands)."""
        messages, self._messages = self._messages, []
        for msg in messages:
            self.t.append(msg.utime * 1e-6)
            for n, g in self.grippers.items():
                est, contact, _ = grip_forces(msg, self.model, self._data, g)
                self.estimate[n].append(est)
                self.contact[n].append(contact)
        pairs, self._in_hand = self._in_hand, []
        for state, objects in pairs:
            pin.framesForwardKinematics(
                self.model, self._data, configuration_from_state(self.model, state)
            )
            for o in objects.objects:
                X_WO = vector_to_pose([*o.position_world, *o.quaternion_world])
                for n, g in self.grippers.items():
                    X_WL = self._data.oMf[self.model.getFrameId(g.base_link)]
                    self.in_hand[n].setdefault(o.object_name, []).append(
                        (state.utime * 1e-6, X_WL.actInv(X_WO))
                    )
        return self

    def hold_motion(
        self, name: str, obj: str, t_from: float, t_to: float
    ) -> tuple[float, float] | None:
        """How far ``obj`` moved in gripper ``name``'s hand over [t_from, t_to] [s]: the largest
        distance [m] and angle [rad] of its pose in the gripper's link from the pose at
        ``t_from``; None without object poses (no simulator) in that window."""
        samples = [X for t, X in self.in_hand.get(name, {}).get(obj, []) if t_from <= t <= t_to]
        if not samples:
            return None
        X0 = samples[0]
        moves = [X0.actInv(X) for X in samples]
        return (
            max(float(np.linalg.norm(m.translation)) for m in moves),
            max(float(np.linalg.norm(pin.log3(m.rotation))) for m in moves),
        )

    def holding_summary(
        self, name: str, t_from: float, t_to: float, target: float, tolerance: float = 1.0
    ) -> dict[str, float]:
        """Contact and estimate statistics of gripper ``name`` over [t_from, t_to] [s], with the
        fraction of contact samples within ``target`` ± ``tolerance`` [N]."""
        t = np.array(self.t)
        sel = (t >= t_from) & (t <= t_to)
        c, e = np.array(self.contact[name])[sel], np.array(self.estimate[name])[sel]
        if not sel.any() or np.isnan(c).all():
            return {"samples": int(sel.sum())}
        return {
            "samples": int(sel.sum()),
            "t_from_s": t_from,
            "t_to_s": t_to,
            "contact_mean_n": float(np.nanmean(c)),
            "contact_median_n": float(np.nanmedian(c)),
            "contact_min_n": float(np.nanmin(c)),
            "contact_max_n": float(np.nanmax(c)),
            "estimate_mean_n": float(np.mean(e)),
            # Sample by sample: how far the estimate the admittance regulates is from the force
            # the jaws actually press with (eq. 3.11-3.13 hold when this is near 0).
            "estimate_minus_contact_median_n": float(np.nanmedian(e - c)),
            "contact_within_tolerance": float(np.mean(np.abs(c - target) <= tolerance)),
        }

    def plot(
        self, path, target: float, spans: dict[str, list[tuple[float, float]]] | None = None
    ) -> None:
        """Estimate and contact force vs time, one panel per gripper, holding spans shaded."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(
            len(self.grippers), 1, figsize=(9, 2.8 * len(self.grippers)), sharex=True, squeeze=False
        )
        for ax, name in zip(axes[:, 0], self.grippers):
            for a, b in (spans or {}).get(name, []):
                ax.axvspan(a, b, color="0.9")
            ax.plot(self.t, self.contact[name], label="contact (mj_contactForce on the jaws)")
            ax.plot(
                self.t, self.estimate[name], label="estimate (effort, eq. 3.11-3.13)", alpha=0.8
            )
            ax.axhline(target, color="k", lw=0.6, ls="--")
            ax.set_ylabel(f"{name} [N]")
            ax.set_xlabel("controller time [s]")
            ax.set_ylim(-2, max(12.0, 2.5 * target))
            ax.legend(loc="upper right", fontsize=7)
        fig.suptitle(f"grip force: {target:g} N target (shaded: the gripper holds)")
        fig.tight_layout()
        fig.savefig(path, dpi=90)
        plt.close(fig)


def recorder_for(ctx: Any, model: pin.Model) -> GripForceRecorder | None:
    """A recorder for a factory context's admittance grippers (``ctx.gripper_joints``) whose jaws
    are declared (robot.yaml) and in ``model``; None when there are none."""
    grippers = {}
    for name, gj in sorted(ctx.gripper_joints.items()):
        g = GripperGeometry.of(ctx.robot, name, gj.parameters, gj.closing_direction)
        if g is None:
            continue
        if all(model.existFrame(b) for b in (g.base_link, *g.plus_jaw, *g.minus_jaw)):
            grippers[name] = g
    return GripForceRecorder(model, grippers) if grippers else None


def holding_windows(
    steps: list, records: list, gripper: str, t_stop: float | None = None
) -> list[tuple[float, float]]:
    """[start, end] [s controller time] of each run of consecutive executed steps in which
    ``gripper`` holds a handle all along (its admittance closes, then holds): from the first such
    step's start to the start of the step after the run (the release) or the last one's end. A
    run the trial stopped in (its last step started and never ended: a failed check, a lost
    grasp) ends at ``t_stop``, when recording stopped, so that the hold that failed is judged."""
    by_index = {r.index: r for r in records if r.utime_start}
    out: list[tuple[float, float]] = []
    start = None
    last = None
    for step in steps:
        r = by_index.get(step.index)
        if r is None:
            continue
        holding = gripper in step.grasps
        if holding and start is None:
            start = r.utime_start * 1e-6
        elif not holding and start is not None:
            out.append((start, r.utime_start * 1e-6))
            start = None
        last = r
    if start is not None and last is not None:
        if last.utime_end:
            end = last.utime_end * 1e-6
        else:
            end = t_stop if t_stop is not None else last.utime_start * 1e-6
        out.append((start, max(end, start)))
    return out


def settled_windows(
    rec: GripForceRecorder,
    name: str,
    windows: list[tuple[float, float]],
    threshold: float,
    settle_s: float = 1.0,
) -> list[tuple[float, float]]:
    """Each holding window from ``settle_s`` after the estimate first reaches ``threshold`` (the
    switch to admittance) to its end; windows where it never does are dropped."""
    t, e = np.array(rec.t), np.array(rec.estimate[name])
    out = []
    for a, b in windows:
        crossed = np.nonzero((t >= a) & (t <= b) & (e >= threshold))[0]
        if crossed.size and t[crossed[0]] + settle_s < b:
            out.append((float(t[crossed[0]] + settle_s), b))
    return out
