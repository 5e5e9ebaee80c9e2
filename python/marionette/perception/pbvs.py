"""Position-based visual-servoing references for a gripper task (thesis 000 §5.2.2-5.2.3).

Eq. 5.1, the task error between two poses: e(T1, T2) = log(T1^-1 T2) in se(3) (the twist
(v, w), in T1's frame, that moves T1 onto T2 in unit time).

Eq. 5.2-5.3, the visual reference. The controller drives the gripper pose g1 computed by
forward kinematics from the encoders; the camera measures the gripper g1^meas (wrist tags) and
the handle H1 (object tags). Calibration errors make g1 != g1^meas, so the reference given to
the g1 task is the handle corrected by that discrepancy,

    T2 = g1 (g1^meas)^-1 H1,           e(g1, T2) = log((g1^meas)^-1 H1),

i.e. the task sees the *measured* gripper-to-handle displacement (the thesis prints
T2 = g1^-1 g1^meas H1 and log(g1^meas H1); the composition above is the one for which
e(g1, T2) = log(g1^-1 T2) reduces to the measured displacement). (g1^meas)^-1 H1 is computed
from the two camera-frame measurements, X_CG^-1 X_CH, so the camera's own pose error cancels.
A goal offset X_HG (handle -> gripper, identity for the grasp, a pre-grasp otherwise) is
appended: T2 = g1 X_CG^-1 X_CH X_HG.

§5.2.3, loss of sight: "the planned reference is used, but shifted using the last information
available": while visible, the offset D = T2 P^-1 between the visual and the planned reference P
is tracked; without measurement, the reference is D_last P(t). The shift is applied on the left
(world frame) because it mostly stands for the object having moved: the whole planned approach
moves rigidly with it.

Switching between sources never jumps: the output is blended from where it was to the new
source over ``blend_time`` with a C2 activation, and the task gain moves between the planned
(high, trajectory following, §5.2.2) and the visual (low, "smoothly reach its goal") gain with
the same activation, as the smooth task switching of the Stack of Tasks does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin


def se3_error(T1: pin.SE3, T2: pin.SE3) -> np.ndarray:
    """Eq. 5.1: log(T1^-1 T2) as (v, w) (6,), expressed in T1's frame."""
    return pin.log6(T1.actInv(T2)).vector


def visual_reference(
    g_fk: pin.SE3, X_CG: pin.SE3, X_CH: pin.SE3, X_HG: pin.SE3 | None = None
) -> pin.SE3:
    """Eq. 5.2: reference T2 of the gripper task from the kinematic gripper pose ``g_fk``
    (world), the measured gripper ``X_CG`` and handle ``X_CH`` (camera frame) and the goal
    offset ``X_HG`` (handle -> desired gripper; identity = grasp)."""
    T2 = g_fk * X_CG.inverse() * X_CH
    return T2 if X_HG is None else T2 * X_HG


def visual_error(X_CG: pin.SE3, X_CH: pin.SE3, X_HG: pin.SE3 | None = None) -> np.ndarray:
    """Eq. 5.3: log((g1^meas)^-1 H1 X_HG), which equals se3_error(g_fk, visual_reference(...))."""
    target = X_CH if X_HG is None else X_CH * X_HG
    return pin.log6(X_CG.actInv(target)).vector


def activation(s: float) -> float:
    """C2 ramp from 0 (s <= 0) to 1 (s >= 1): 6 s^5 - 15 s^4 + 10 s^3."""
    s = min(1.0, max(0.0, s))
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def interpolate(T_a: pin.SE3, T_b: pin.SE3, alpha: float) -> pin.SE3:
    """Geodesic T_a exp(alpha log(T_a^-1 T_b)) (alpha = 0: T_a, 1: T_b)."""
    return T_a * pin.exp6(alpha * pin.log6(T_a.actInv(T_b)))


@dataclass(frozen=True)
class VisualMeasurement:
    """Gripper and handle measured in one camera frame at time ``t`` [s]."""

    t: float
    X_CG: pin.SE3  # camera <- gripper (from the wrist tags and their known mount)
    X_CH: pin.SE3  # camera <- handle (from the object's tags and the handle's placement)


@dataclass(frozen=True)
class PbvsOutput:
    reference: pin.SE3  # T2 for the gripper task (world)
    gain: float  # task gain [1/s]
    mode: str  # "planned" (never seen), "visual", "fallback" (planned shifted by the last offset)
    offset: pin.SE3 | None  # D = T2 P^-1 at the last measurement


class PbvsReference:
    """The reference and gain of one gripper's PBVS task, updated at the controller's rate.

    ``update(t, g_fk, planned, measurement)``: ``g_fk`` the gripper by forward kinematics,
    ``planned`` the planned reference P(t), ``measurement`` the latest visual measurement or
    None. A measurement older than ``timeout`` [s] counts as lost sight.
    """

    def __init__(
        self,
        visual_gain: float = 1.0,
        planned_gain: float = 10.0,
        blend_time: float = 0.5,
        timeout: float = 0.2,
        X_HG: pin.SE3 | None = None,
    ) -> None:
        if not (visual_gain > 0 and planned_gain > 0 and blend_time > 0 and timeout > 0):
            raise ValueError("gains, blend_time and timeout must be > 0")
        self.visual_gain = visual_gain
        self.planned_gain = planned_gain
        self.blend_time = blend_time
        self.timeout = timeout
        self.X_HG = X_HG
        self._mode = "planned"
        self._offset: pin.SE3 | None = None
        self._last: PbvsOutput | None = None
        self._switch_t = -np.inf
        self._from_ref: pin.SE3 | None = None
        self._from_gain = planned_gain

    def update(
        self, t: float, g_fk: pin.SE3, planned: pin.SE3, measurement: VisualMeasurement | None
    ) -> PbvsOutput:
        visible = measurement is not None and t - measurement.t <= self.timeout
        if measurement is not None and visible:
            target = visual_reference(g_fk, measurement.X_CG, measurement.X_CH, self.X_HG)
            self._offset = target * planned.inverse()
            mode, gain = "visual", self.visual_gain
        elif self._offset is not None:
            target, mode, gain = self._offset * planned, "fallback", self.planned_gain
        else:
            target, mode, gain = planned, "planned", self.planned_gain
        if mode != self._mode and self._last is not None:
            # Start a blend from where the output is now.
            self._switch_t = t
            self._from_ref = self._last.reference
            self._from_gain = self._last.gain
        self._mode = mode
        alpha = activation((t - self._switch_t) / self.blend_time)
        if self._from_ref is not None and alpha < 1.0:
            reference = interpolate(self._from_ref, target, alpha)
            gain = self._from_gain + alpha * (gain - self._from_gain)
        else:
            reference = target
        self._last = PbvsOutput(reference, float(gain), mode, self._offset)
        return self._last


def task_reference_message(
    task_name: str,
    controller_id: int,
    utime: int,
    references: list[pin.SE3],
    dt_us: int,
    last_chunk: bool = False,
):
    """``lcmt_task_reference`` of SE(3) samples (x y z qw qx qy qz), no feed-forward."""
    from marionette import lcmt_task_reference

    msg = lcmt_task_reference()
    msg.utime = utime
    msg.task_name = task_name
    msg.controller_id = controller_id
    msg.dt_us = dt_us
    msg.num_samples = len(references)
    msg.value_size = 7
    msg.derivative_size = 0
    values = []
    for T in references:
        q = pin.Quaternion(T.rotation)
        q.normalize()
        values.append([*map(float, T.translation), q.w, q.x, q.y, q.z])
    msg.value = values
    msg.derivative = [[] for _ in references]
    msg.last_chunk = last_chunk
    return msg
