"""The supervisor's decisions as a function of the messages it receives.

:class:`DecisionMachine` holds no clock, thread or I/O: it is fed, one at a time and in arrival
order, the controller's statuses (CONTROLLER_STATUS, whose ``utime`` is the controller tick), its
commands (ROBOT_COMMAND: the velocity the safety filter passes, read by the end check), the
events of other processes (SUPERVISOR_EVENT) and the step's own facts (``STEP``: controller id
and end-check thresholds from the plan, the streamer's reference start/end times, a switch sent
again) or a wall-clock timeout (``TIMER``), and returns the :class:`Decision` each input caused.
The live supervisor acts on them (thesis 000 §3.2.5.2: start check, end of reference, end check,
events);
``marionette replay LOG --supervisor`` feeds the recorded inputs of a log to a fresh machine and
compares what it decides with the recorded decisions (:func:`replay_decisions`).

Decision tick: the ``utime`` of the last CONTROLLER_STATUS fed (events are applied at the tick of
the status that preceded them), so the same message sequence gives the same decisions at the same
ticks whatever the wall-clock timing of the supervisor's loop.

Step statuses:  starting -> waiting_start_check -> accepted -> running -> waiting_end_check -> ended
                (any of them -> failed); waiting_start_check -> settling -> resend ->
                waiting_start_check when a refused switch is retried.

Switch and end check, one semantics. The controller swaps a new controller in only when the
command it computes at that tick is within ``max_switch_velocity_jump`` (‖Δv‖∞) of the command
applied; the new controller's references start where the robot is (its streams hold the current
value until their first sample), so its first command is ~0 and the jump is the command the
previous controller still applies: the gain times what the robot lags behind its reference. The
end check therefore tests that lag where it matters: besides every task error below its threshold,
the command of a status-time ROBOT_COMMAND after the last sample must be at most
``REST_FRACTION`` of the next controller's jump bound (joints an admittance task ramps are left
out: the next controller continues their ramp). A switch refused all the same (a transient: a
grasp weld closing, a slip) is retried up to ``switch_retries`` times: the previous controller
holds its last reference, and once its command is back under that bound (or after
``settle_timeout_us``) the supervisor sends the controller again under a new id.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from marionette.control.spec import HOLD_CONTROLLER_ID

STATUS = "CONTROLLER_STATUS"
COMMAND = "ROBOT_COMMAND"
EVENT = "SUPERVISOR_EVENT"
STEP = "STEP"
TIMER = "TIMER"
FED_CHANNELS = (
    STEP,
    TIMER,
)  # inputs the supervisor itself produces: recorded, fed back, not decided

FAILURES = (
    "switch_refused",
    "spec_rejected",
    "switch_timeout",
    "reference_starved",
    "controller_holding",
    "controller_estopped",
    "abort",
    "left_manifold",
    "grasp_lost",
    "end_check_failed",
    "approval_timeout",
)
# A step ends, and a refused switch is sent again, only when the command is at most this fraction
# of the (next) controller's switch bound: half of it is left for what changes until the swap.
REST_FRACTION = 0.5


def event_message(utime: int, name: str, source: str, detail: str = "", value: float = 0.0) -> Any:
    """A SUPERVISOR_EVENT message (``lcmt_supervisor_event``) as every process writes one: the
    machine acts on ``name`` from any ``source`` but the supervisor's own (see :meth:`on_event`)."""
    from marionette import lcmt_supervisor_event

    msg = lcmt_supervisor_event()
    msg.utime = int(utime)
    msg.name, msg.source, msg.detail, msg.value = name, source, detail, float(value)
    return msg


@dataclass(frozen=True)
class Decision:
    """One transition of the FSM: ``event`` taken at controller tick ``utime`` because of the input
    on ``input_channel`` stamped ``input_utime``, having read ``inputs``."""

    utime: int
    step_index: int
    transition: str
    event: str
    from_status: str
    to_status: str
    detail: str
    input_channel: str
    input_utime: int
    inputs: dict[str, float] = field(default_factory=dict)

    def key(self) -> tuple:
        """What a replay must reproduce (the inputs are compared separately, with their values)."""
        return (self.utime, self.step_index, self.event, self.from_status, self.to_status)

    def to_lcm(self, seq: int, plan_name: str) -> Any:
        from marionette import lcmt_supervisor_decision

        msg = lcmt_supervisor_decision()
        msg.utime, msg.seq, msg.plan_name = int(self.utime), int(seq), plan_name
        msg.step_index, msg.transition, msg.event = (
            int(self.step_index),
            self.transition,
            self.event,
        )
        msg.from_status, msg.to_status, msg.detail = self.from_status, self.to_status, self.detail
        msg.input_channel, msg.input_utime = self.input_channel, int(self.input_utime)
        msg.num_inputs = len(self.inputs)
        msg.input_name = list(self.inputs)
        msg.input_value = [float(v) for v in self.inputs.values()]
        return msg

    @staticmethod
    def from_lcm(msg: Any) -> Decision:
        return Decision(
            int(msg.utime),
            int(msg.step_index),
            msg.transition,
            msg.event,
            msg.from_status,
            msg.to_status,
            msg.detail,
            msg.input_channel,
            int(msg.input_utime),
            dict(zip(msg.input_name, msg.input_value)),
        )


@dataclass(frozen=True)
class StepRest:
    """The command bounds of one step (module doc): ``switch_jump``, its controller's
    ``max_switch_velocity_jump``; ``next_switch_jump``, the next controller's (inf: the last
    step, no end-of-step rest check); refused switches retried ``switch_retries`` times, each
    after at most ``settle_timeout_us`` of controller time; ``excluded_joints`` ramped by an
    admittance task (left out of the rest checks)."""

    switch_jump: float = float("inf")
    next_switch_jump: float = float("inf")
    switch_retries: int = 0
    settle_timeout_us: int = 0
    excluded_joints: tuple[str, ...] = ()

    def inputs(self) -> dict[str, float]:
        """As a decision's inputs (none for the default: logs of runs without rest checks replay
        unchanged)."""
        if self == StepRest():
            return {}
        out = {
            "switch_jump": self.switch_jump,
            "next_switch_jump": self.next_switch_jump,
            "switch_retries": float(self.switch_retries),
            "settle_timeout_us": float(self.settle_timeout_us),
        }
        out.update({f"rest_excluded:{j}": 1.0 for j in self.excluded_joints})
        return out

    @staticmethod
    def from_inputs(inputs: dict[str, float]) -> StepRest:
        if "switch_jump" not in inputs:
            return StepRest()
        return StepRest(
            inputs["switch_jump"],
            inputs["next_switch_jump"],
            int(inputs["switch_retries"]),
            int(inputs["settle_timeout_us"]),
            tuple(n[len("rest_excluded:") :] for n in inputs if n.startswith("rest_excluded:")),
        )


class DecisionMachine:
    """The supervisor FSM's decision function, one step at a time (see the module doc)."""

    def __init__(self) -> None:
        self.tick = 0  # [us] utime of the last status fed
        self.status = "idle"
        self.step_index = -1
        self.transition = ""
        self.controller_id = 0
        self.thresholds: dict[str, float] = {}
        self.converge_timeout_us = 0
        self.end_utime = 0  # [us] last reference sample (after a force stop: the held one)
        self.reference_sent = False  # every chunk streamed
        # A force event cuts the reference once per step, also after everything was streamed: a
        # chunk redefines the controller's stream from its first sample on (reference_stream.cc).
        self.reference_stopped = False
        self.awaiting = ""  # event name awaited in "awaiting_approval"
        # The last command (ROBOT_COMMAND): its tick, joints and velocities.
        self.command_utime = -1
        self._command: tuple[list[str], list[float]] = ([], [])
        self.rest_excluded: frozenset[str] = frozenset()
        self.end_rest_speed = float("inf")  # the end check's bound (inf: not checked)
        self.switch_rest_speed = float("inf")  # a refused switch is resent below this
        self.switch_retries = 0  # refused switches still to retry in this step
        self.settle_timeout_us = 0
        self.refused_tick = 0

    # ---- inputs -----------------------------------------------------------------------------
    def feed(self, channel: str, msg: Any) -> list[Decision]:
        """Feeds one received message (CONTROLLER_STATUS or SUPERVISOR_EVENT)."""
        if channel == STATUS:
            return self.on_status(msg)
        if channel == COMMAND:
            return self.on_command(msg)
        if channel == EVENT:
            return self.on_event(msg)
        raise ValueError(
            f"the decision machine reads {STATUS}, {COMMAND} and {EVENT}, not {channel!r}"
        )

    def begin_step(
        self,
        step_index: int,
        transition: str,
        controller_id: int,
        thresholds: dict[str, float],
        converge_timeout_us: int,
        approval: bool = False,
        rest: StepRest | None = None,
    ) -> Decision:
        """STEP: a new step, its controller id and end-check thresholds (from the plan), and the
        command bounds of its switch and end check (``rest``; None: neither checked nor
        retried)."""
        self.step_index, self.transition = int(step_index), transition
        self.controller_id = int(controller_id)
        self.thresholds = dict(thresholds)
        self.converge_timeout_us = int(converge_timeout_us)
        self.end_utime, self.reference_sent, self.reference_stopped = 0, False, False
        rest = rest or StepRest()
        self.end_rest_speed = REST_FRACTION * rest.next_switch_jump
        self.switch_rest_speed = REST_FRACTION * rest.switch_jump
        self.switch_retries = int(rest.switch_retries)
        self.settle_timeout_us = int(rest.settle_timeout_us)
        self.rest_excluded = frozenset(rest.excluded_joints)
        inputs = {
            "controller_id": float(controller_id),
            "converge_timeout_us": float(converge_timeout_us),
            "approval": float(approval),
        }
        inputs.update({f"threshold:{n}": float(t) for n, t in thresholds.items()})
        inputs.update(rest.inputs())
        if approval:
            self.awaiting = "approve"
            return self._decide(
                "step_started",
                "awaiting_approval",
                f"{step_index} {transition}",
                STEP,
                self.tick,
                inputs,
            )
        return self._decide(
            "step_started",
            "waiting_start_check",
            f"{step_index} {transition}",
            STEP,
            self.tick,
            inputs,
        )

    def start_reference(self, start_utime: int, end_utime: int) -> Decision:
        """STEP: the streamer plays the references from ``start_utime`` to ``end_utime`` [us]."""
        self._expect("accepted")
        self.end_utime = int(end_utime)
        return self._decide(
            "reference_started",
            "running",
            f"controller {self.controller_id}",
            STEP,
            self.tick,
            {"start_utime": float(start_utime), "end_utime": float(end_utime)},
        )

    def reference_end(self, end_utime: int, sent: bool) -> Decision:
        """STEP: the streamer's new last sample (after a force stop) or its last chunk sent."""
        self.end_utime, self.reference_sent = int(end_utime), bool(sent)
        return self._decide(
            "reference_end",
            self.status,
            "",
            STEP,
            self.tick,
            {"end_utime": float(end_utime), "sent": float(sent)},
        )

    def resend_switch(self, controller_id: int) -> Decision:
        """STEP: the refused controller sent again under the new id ``controller_id``."""
        self._expect("resend")
        self.controller_id = int(controller_id)
        return self._decide(
            "switch_resent",
            "waiting_start_check",
            f"controller {controller_id}",
            STEP,
            self.tick,
            {"controller_id": float(controller_id)},
        )

    def on_command(self, msg: Any) -> list[Decision]:
        """ROBOT_COMMAND: the command applied at ``msg.utime``, kept for the rest checks."""
        self.command_utime = int(msg.utime)
        self._command = (list(msg.joint_name), list(msg.joint_velocity))
        return []

    def command_speed(self) -> tuple[float, str]:
        """‖v‖∞ of the last command over the joints the rest checks read, and its joint."""
        speed, joint = (0.0, "") if self.command_utime >= 0 else (float("inf"), "")
        for name, v in zip(*self._command):
            if name not in self.rest_excluded and abs(v) > speed:
                speed, joint = abs(v), name
        return speed, joint

    def _at_rest(self, after_utime: int, bound: float) -> bool:
        """The last command was applied after ``after_utime`` and is within ``bound``."""
        return bound == float("inf") or (
            self.command_utime > after_utime and self.command_speed()[0] <= bound
        )

    def _command_inputs(self) -> dict[str, float]:
        return {
            "command_utime": float(self.command_utime),
            "command_speed": self.command_speed()[0],
        }

    def timeout(self, event: str, detail: str) -> Decision:
        """TIMER: a wall-clock wait ran out (``switch_timeout``, ``approval_timeout``)."""
        if event not in FAILURES:
            raise ValueError(f"unknown timeout {event!r}")
        return self._decide(event, "failed", detail, TIMER, self.tick, {})

    def on_status(self, st: Any) -> list[Decision]:
        self.tick = int(st.utime)
        s, cid = self.status, self.controller_id
        ins = {"active_controller_id": float(st.active_controller_id)}
        if s == "waiting_start_check":
            tag = f"(id {cid})"
            # Accepted when the loop snapshot shows the new active id (the controller publishes
            # the decision text with the first status of the deciding tick, never before it).
            if st.active_controller_id == cid:
                return [
                    self._status_decision(
                        "switch_accepted", "accepted", f"controller {cid}", st, ins
                    )
                ]
            if tag in st.last_switch_result and not st.last_switch_result.startswith("accepted"):
                return [self._refused(st.last_switch_result, st, ins)]
            if tag in st.last_rejection:
                # A refused switch is also counted as a rejection ("CONTROLLER_SPEC: refused
                # controller ... command jump"), which can reach a status before the switch result
                # does (that one waits for the deciding tick): it is still a refused switch.
                if "refused controller" in st.last_rejection:
                    return [self._refused(st.last_rejection, st, ins)]
                return [
                    self._status_decision("spec_rejected", "failed", st.last_rejection, st, ins)
                ]
            return []
        if s == "settling":
            # The previous controller holds its last reference; resend once it is at rest.
            settled = self._at_rest(self.refused_tick, self.switch_rest_speed)
            if settled or self.tick >= self.refused_tick + self.settle_timeout_us:
                ins.update(self._command_inputs())
                ins["refused_tick"] = float(self.refused_tick)
                how = "at rest" if settled else "settle timeout"
                return [self._status_decision("switch_resend", "resend", how, st, ins)]
            return []
        if s not in ("running", "waiting_end_check"):
            return []
        # Holding with this step's controller, or with the controller's own hold controller that
        # replaced it (repeated time-budget overruns): the step failed.
        if st.mode in ("holding", "estopped") and st.active_controller_id in (
            cid,
            HOLD_CONTROLLER_ID,
        ):
            event = "reference_starved" if "watchdog" in st.mode_reason else "controller_" + st.mode
            return [self._status_decision(event, "failed", st.mode_reason, st, ins)]
        out = []
        if s == "running":
            if self.tick < self.end_utime:
                return []
            ins["end_utime"] = float(self.end_utime)
            out.append(
                self._status_decision(
                    "end_of_reference",
                    "waiting_end_check",
                    f"{self.step_index} {self.transition}",
                    st,
                    ins,
                )
            )
        if self.tick > self.end_utime:  # the end check reads statuses after the last sample
            errors = dict(zip(st.task_name, st.task_error_norm))
            ins = {f"error:{n}": float(errors.get(n, float("inf"))) for n in self.thresholds}
            ins["end_utime"] = float(self.end_utime)
            above = {
                n: errors.get(n)
                for n, thr in self.thresholds.items()
                if errors.get(n, float("inf")) > thr
            }
            if self.end_rest_speed != float("inf"):
                ins.update(self._command_inputs())
                if not self._at_rest(self.end_utime, self.end_rest_speed):
                    speed, joint = self.command_speed()
                    above[f"command {joint or '-'} [rad/s]"] = speed
            if not above:
                out.append(self._status_decision("end_check_passed", "ended", "", st, ins))
            elif self.tick > self.end_utime + self.converge_timeout_us:
                out.append(
                    self._status_decision(
                        "end_check_failed",
                        "failed",
                        f"step {self.step_index}: errors above threshold {above}",
                        st,
                        ins,
                    )
                )
        return out

    def on_event(self, ev: Any) -> list[Decision]:
        ins = {"value": float(ev.value)}
        if self.status == "awaiting_approval":
            if ev.name == self.awaiting:
                self.awaiting = ""
                return [
                    self._decide("approved", "waiting_start_check", ev.source, EVENT, ev.utime, ins)
                ]
            if ev.name == "abort":
                return [
                    self._decide(
                        "abort", "failed", ev.detail or f"from {ev.source}", EVENT, ev.utime, ins
                    )
                ]
            return []
        if self.status not in ("waiting_start_check", "accepted", "running", "waiting_end_check"):
            return []
        if ev.name == "force_threshold" and self.status == "running" and not self.reference_stopped:
            self.reference_stopped = True
            return [
                self._decide(
                    "reference_stopped", "running", f"force {ev.value:.3g} N", EVENT, ev.utime, ins
                )
            ]
        if ev.name in ("abort", "left_manifold", "grasp_lost") and self.status in (
            "accepted",
            "running",
            "waiting_end_check",
        ):
            return [
                self._decide(
                    ev.name, "failed", ev.detail or f"from {ev.source}", EVENT, ev.utime, ins
                )
            ]
        return []

    # ---- helpers ----------------------------------------------------------------------------
    def _refused(self, detail: str, st: Any, ins: dict[str, float]) -> Decision:
        """A refused switch: retried while retries are left and the refusal was a command jump
        (an estop latched is not a transient), failed otherwise."""
        if self.switch_retries > 0 and "command jump" in detail:
            self.switch_retries -= 1
            self.refused_tick = self.tick
            ins["retries_left"] = float(self.switch_retries)
            return self._status_decision("switch_retry", "settling", detail, st, ins)
        return self._status_decision("switch_refused", "failed", detail, st, ins)

    def _expect(self, status: str) -> None:
        if self.status != status:
            raise RuntimeError(f"decision machine: expected status {status!r}, in {self.status!r}")

    def _status_decision(
        self, event: str, to: str, detail: str, st: Any, inputs: dict[str, float]
    ) -> Decision:
        return self._decide(event, to, detail, STATUS, int(st.utime), inputs)

    def _decide(
        self,
        event: str,
        to: str,
        detail: str,
        channel: str,
        input_utime: int,
        inputs: dict[str, float],
    ) -> Decision:
        d = Decision(
            self.tick,
            self.step_index,
            self.transition,
            event,
            self.status,
            to,
            detail,
            channel,
            int(input_utime),
            inputs,
        )
        self.status = to
        return d


# ---- offline replay -----------------------------------------------------------------------------
@dataclass
class DecisionReplay:
    """Verdict of :func:`replay_decisions`."""

    ok: bool
    recorded: int  # decisions in the log
    replayed: int  # decisions the offline machine took
    statuses: int  # CONTROLLER_STATUS messages fed
    events: int  # SUPERVISOR_EVENT messages fed
    first_divergence: str = ""  # the first diverging tick and decision, "" when identical
    problems: list[str] = field(default_factory=list)


def replay_decisions(recorded: list[Decision], inputs: Iterable[tuple[str, Any]]) -> DecisionReplay:
    """Feeds ``inputs`` ((channel, message) in log order: CONTROLLER_STATUS and other sources'
    SUPERVISOR_EVENT) to a fresh :class:`DecisionMachine`, with the recorded STEP/TIMER inputs
    re-fed at their ticks, and compares the decisions with ``recorded`` (in order)."""
    fed = [d for d in recorded if d.input_channel in FED_CHANNELS]
    machine = DecisionMachine()
    replayed: list[Decision] = []
    counts = {STATUS: 0, COMMAND: 0, EVENT: 0}
    k = 0

    def refeed(before_utime: int | None) -> None:
        # A STEP/TIMER input taken at tick U was fed after every status stamped <= U and before
        # the first one stamped > U (statuses reach the machine in tick order).
        nonlocal k
        while k < len(fed) and (before_utime is None or fed[k].utime < before_utime):
            replayed.append(_refeed(machine, fed[k]))
            k += 1

    for channel, msg in inputs:
        refeed(int(msg.utime) if channel == STATUS else machine.tick + 1)
        counts[channel] += 1
        replayed.extend(machine.feed(channel, msg))
    refeed(None)

    result = DecisionReplay(True, len(recorded), len(replayed), counts[STATUS], counts[EVENT])
    for i, (r, p) in enumerate(zip(recorded, replayed)):
        if r.key() != p.key() or not _same_inputs(r.inputs, p.inputs):
            result.ok = False
            result.first_divergence = (
                f"decision {i} at tick {r.utime} us (step {r.step_index} {r.transition}): recorded "
                f"{r.event} {r.from_status}->{r.to_status} {r.inputs}, replayed at tick {p.utime}: "
                f"{p.event} {p.from_status}->{p.to_status} {p.inputs}"
            )
            return result
    if len(recorded) != len(replayed):
        result.ok = False
        longer, which = (
            (recorded, "recorded") if len(recorded) > len(replayed) else (replayed, "replayed")
        )
        d = longer[min(len(recorded), len(replayed))]
        result.first_divergence = (
            f"decision {min(len(recorded), len(replayed))} at tick {d.utime} us: only "
            f"{which}: {d.event} {d.from_status}->{d.to_status} (step {d.step_index})"
        )
    return result


def _refeed(machine: DecisionMachine, d: Decision) -> Decision:
    """Re-applies a recorded STEP/TIMER input to ``machine``."""
    i = d.inputs
    if d.event == "step_started":
        thresholds = {n[len("threshold:") :]: v for n, v in i.items() if n.startswith("threshold:")}
        return machine.begin_step(
            d.step_index,
            d.transition,
            int(i["controller_id"]),
            thresholds,
            int(i["converge_timeout_us"]),
            bool(i.get("approval", 0.0)),
            StepRest.from_inputs(i),
        )
    if d.event == "switch_resent":
        return machine.resend_switch(int(i["controller_id"]))
    if d.event == "reference_started":
        return machine.start_reference(int(i["start_utime"]), int(i["end_utime"]))
    if d.event == "reference_end":
        return machine.reference_end(int(i["end_utime"]), bool(i["sent"]))
    if d.input_channel == TIMER:
        return machine.timeout(d.event, d.detail)
    raise ValueError(f"recorded {d.input_channel} input {d.event!r} cannot be re-fed")


def _same_inputs(a: dict[str, float], b: dict[str, float]) -> bool:
    # Values went through LCM doubles both ways: equal bit for bit, inf included.
    return a.keys() == b.keys() and all(a[n] == b[n] for n in a)
