"""The supervisor (thesis 000 §3.2.5.2, §3.3.6): a finite-state machine generated from the plan,
one state per step (transition crossed), run against a live marionette-controller.

Per step:
  start_check   grasps released at this step's start are opened (simulated: weld off); the
                step's controller spec is sent; the controller swaps it in only if its command
                does not jump (the start check, done at the tick of the swap), else it refuses:
                the previous controller holds its last reference until its command is at rest,
                and the spec is sent again (``switch_retry``, at most ``switch_retries`` times),
                then ``switch_refused``, failed;
  running       the planned references are streamed ahead of the controller's clock; events:
                ``force_threshold`` ends the reference early (the goal is already reached),
                ``abort``, ``left_manifold`` (:mod:`.monitor`) and ``grasp_lost``
                (:mod:`.grip_monitor`) fail; the controller going to hold on its watchdog ->
                failed;
  end_check     the whole reference has been played (``end_of_reference``), every task error
                is below its threshold (:data:`factory.END_THRESHOLDS`) and the command is at
                rest enough for the next switch to be accepted (:mod:`.decisions`) within
                ``converge_timeout_s`` of controller time, else ``end_check_failed``;
  grasps        grasps created at the step's end are closed (simulated: weld on);
  approval      with ``step_mode``, waits for an ``approve`` event (the operator of §3.4.2).
On any failure the supervisor sends COMMAND hold and ends in ``failed`` (the robot holds).
From its first spec on, its client's bus sends the heartbeat (COMMAND ``heartbeat`` every 20 ms,
:mod:`marionette.lcm_bus`; the streamed chunks count too): a supervisor that dies leaves the robot
held by the controller within its ``--supervisor-timeout``, not playing the 4 s streamed ahead;
``marionette supervise`` started again estimates where the plan stands and resumes from there.

State on SUPERVISOR_STATE (10 Hz and on change), events on SUPERVISOR_EVENT; events from other
sources (``marionette fsm inject``) are read from SUPERVISOR_EVENT too.

Before any of it, :meth:`Supervisor.prepare` samples every step's references within the joints'
velocity bounds, re-timing the steps a rewrite (the gaze) made too fast
(:func:`references.shaped_trajectory`).

Every decision above is taken by :class:`decisions.DecisionMachine` from the received
CONTROLLER_STATUS / ROBOT_COMMAND / SUPERVISOR_EVENT messages, fed one at a time in arrival
order, at the tick of the last status (never the wall clock), and published on
SUPERVISOR_DECISION with its inputs:
``marionette replay LOG --supervisor`` re-takes them offline. With :attr:`Supervisor.journal`
set, the supervisor also writes every input it feeds its machine, in that order, and every
decision to that file (an LCM log, :data:`JOURNAL_NAME` in a demo's report folder): the record
to replay, complete whatever a network logger drops.
"""

from __future__ import annotations

import dataclasses
import gc
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lcm
from marionette import (
    channels,
    lcmt_controller_status,
    lcmt_robot_command,
    lcmt_supervisor_event,
    lcmt_supervisor_state,
)
from marionette.control.client import ControllerClient
from marionette.control.spec import ControllerSpec
from marionette.execution import decisions
from marionette.execution.decisions import Decision, DecisionMachine, StepRest, event_message
from marionette.execution.factory import END_THRESHOLDS
from marionette.execution.plan_steps import PlanRobotMap, Step
from marionette.execution.references import (
    Rewrite,
    StepTiming,
    StepTrajectory,
    grip_change_s,
    shaped_trajectory,
    velocity_limits,
)
from marionette.execution.streamer import ReferenceStreamer

SOURCE = "supervisor"
# The supervisor's own record of a run beside the run's LCM log (:attr:`Supervisor.journal`).
JOURNAL_NAME = "supervisor-journal.lcmlog"
INJECTABLE = ("abort", "force_threshold", "approve", "left_manifold", "grasp_lost")


class SupervisorFailure(RuntimeError):
    """Why the FSM went to ``failed`` (its ``event`` names the event raised)."""

    def __init__(self, event: str, detail: str) -> None:
        super().__init__(f"{event}: {detail}")
        self.event = event
        self.detail = detail


@dataclass
class SupervisorOptions:
    max_joint_velocity: float = 0.5  # [rad/s] time law of the planned paths
    min_step_duration: float = 0.5  # [s]
    dt_us: int = 1000  # reference sampling: the controller's period
    chunk_samples: int = 200
    lookahead_s: float = 4.0  # controller time streamed ahead (< 5 s kept)
    start_delay_us: int = 100_000  # first sample this far after the swap is seen
    accept_timeout_s: float = 20.0  # [s wall] waiting for the swap decision
    converge_timeout_s: float = 3.0  # [s controller time] end check
    # The end check waits for a command at rest and a refused switch is retried (decisions.py);
    # False: neither (the machine's behaviour before them).
    rest_checks: bool = True
    switch_retries: int = 3
    settle_timeout_s: float = 3.0  # [s controller time] before a refused switch is sent again
    simulated_grasps: bool = True  # SIM_COMMAND attach/detach welds (MuJoCo backend)
    step_mode: bool = False  # wait for "approve" before each step
    approval_timeout_s: float = 600.0


@dataclass
class StepRecord:
    """What happened in one step (for the report)."""

    index: int
    transition: str
    kind: str
    controller_id: int = 0
    utime_start: int = 0  # swap seen [us controller time]
    utime_reference_start: int = 0
    utime_reference_end: int = 0
    utime_end: int = 0  # end check passed
    wall_s: float = 0.0
    duration_s: float = 0.0  # planned duration of the reference
    chunks: int = 0
    switch_retries: int = 0  # refused switches sent again
    retimed: float = 1.0  # the step slowed down for its references to respect the joints' bounds
    retimed_for: str = ""
    lean: float = 0.0  # [rad] the torso lean the gaze added to see the servoed object
    min_lookahead_ms: float | None = None
    final_errors: dict[str, float] = field(default_factory=dict)
    max_errors: dict[str, float] = field(default_factory=dict)
    error_trace: list[tuple[int, dict[str, float]]] = field(default_factory=list)
    events: list[str] = field(default_factory=list)
    result: str = ""


@dataclass
class SupervisorResult:
    success: bool
    state: str
    reason: str
    records: list[StepRecord]
    events: list[tuple[int, str, str]]


def prepare_trajectories(
    steps: list[Step],
    specs: list[ControllerSpec],
    robot_map: PlanRobotMap,
    options: SupervisorOptions,
    first: int = 0,
    timing: Callable[[Step, ControllerSpec], StepTiming] | None = None,
    rewrites: list[Rewrite] | tuple[Rewrite, ...] = (),
    skip: set[int] | None = None,
) -> dict[int, StepTrajectory]:
    """The references the supervisor streams for the steps from ``first`` on (step index ->
    trajectory): each step sampled within the joints' velocity bounds
    (:func:`references.velocity_limits` of ``options.max_joint_velocity``), played as ``timing``
    says, held at its start while a gripper changes its grip (:func:`references.grip_change_s`),
    rewritten by ``rewrites`` (the first step run knows it is), re-timed where a rewrite made it
    too fast (:func:`references.shaped_trajectory`)."""
    limits = velocity_limits(robot_map.model, options.max_joint_velocity)
    out: dict[int, StepTrajectory] = {}
    for k in range(first, len(steps)):
        step, spec = steps[k], specs[k]
        if skip and step.index in skip:
            continue
        step_timing = timing(step, spec) if timing is not None else StepTiming()
        grip = grip_change_s(step, steps[k - 1] if k > 0 else None, spec, robot_map.robot)
        if grip > step_timing.lead_in_s:
            step_timing = dataclasses.replace(step_timing, lead_in_s=grip)
        out[step.index] = shaped_trajectory(
            step,
            spec,
            robot_map,
            limits,
            options.dt_us * 1e-6,
            options.min_step_duration,
            step_timing,
            rewrites,
            first=step.index == first,
        )
    return out


class Supervisor:
    """Runs ``steps`` with their ``specs`` on the controller behind ``client``."""

    def __init__(
        self,
        client: ControllerClient,
        steps: list[Step],
        specs: list[ControllerSpec],
        robot_map: PlanRobotMap,
        options: SupervisorOptions | None = None,
        plan_name: str = "plan",
        id_base: int | None = None,
    ) -> None:
        if len(steps) != len(specs):
            raise ValueError(f"{len(steps)} steps but {len(specs)} controller specs")
        self.client = client
        self.steps = steps
        self.specs = specs
        self.robot_map = robot_map
        self.options = options or SupervisorOptions()
        self.plan_name = plan_name
        # Controller ids are never reused by one controller process: start from the clock.
        self._next_id = id_base if id_base is not None else int(time.time() * 10) % 1_000_000_000
        self.trajectories: dict[int, StepTrajectory] = {}
        # How each step is played beyond its time law, and the rewrites of its references
        # (the gaze): both applied by :meth:`prepare`.
        self.timing: Callable[[Step, ControllerSpec], StepTiming] = lambda step, spec: StepTiming()
        self.rewrites: list[Rewrite] = []
        self.servo: Any = None  # a visual_servo.VisualServo: corrects the pbvs tasks' references
        self.journal: Path | None = None  # where :meth:`run` records inputs and decisions
        self._journal: Any = None  # the open lcm.EventLog while it runs
        self.state = "idle"
        self.status = ""
        self.detail = ""
        self.step_index = -1
        self.events: list[tuple[int, str, str]] = []
        self._inputs: list[tuple[str, Any]] = []  # (channel, message) in arrival order
        self._lock = threading.Lock()
        self.machine = DecisionMachine()
        self.decisions: list[Decision] = []
        self._taken: list[Decision] = []  # decisions not yet awaited by the step's flow
        self._publish_stop = threading.Event()
        client.bus.subscribe(channels.SUPERVISOR_EVENT, lcmt_supervisor_event, self._on_event)
        client.bus.subscribe(channels.CONTROLLER_STATUS, lcmt_controller_status, self._on_status)
        if self.options.rest_checks:
            client.bus.subscribe(channels.ROBOT_COMMAND, lcmt_robot_command, self._on_command)

    # ---- preparation ------------------------------------------------------------------------
    def prepare(self, first: int = 0) -> float:
        """Samples every step's references from ``first`` on that :attr:`trajectories` lacks
        (:func:`prepare_trajectories`, with :attr:`timing` and :attr:`rewrites`); returns the
        time it took [s]."""
        t0 = time.perf_counter()
        self.trajectories.update(
            prepare_trajectories(
                self.steps,
                self.specs,
                self.robot_map,
                self.options,
                first,
                self.timing,
                self.rewrites,
                skip=set(self.trajectories),
            )
        )
        return time.perf_counter() - t0

    # ---- LCM --------------------------------------------------------------------------------
    def _on_event(self, msg: Any) -> None:
        if msg.source != SOURCE:
            with self._lock:
                self._inputs.append((decisions.EVENT, msg))

    def _on_status(self, msg: Any) -> None:
        with self._lock:
            self._inputs.append((decisions.STATUS, msg))

    def _on_command(self, msg: Any) -> None:
        with self._lock:
            self._inputs.append((decisions.COMMAND, msg))

    def _later_or_input(self, utime: int) -> Callable[[ControllerClient], bool]:
        """A wait condition: the controller's clock past ``utime``, or a message to feed."""
        return lambda c: c.utime() > utime or bool(self._inputs)

    def _next_input(self) -> tuple[str, Any] | None:
        with self._lock:
            return self._inputs.pop(0) if self._inputs else None

    def _decided(self, d: Decision) -> Decision:
        """Publishes a decision of the machine on SUPERVISOR_DECISION, journals and keeps it."""
        msg = d.to_lcm(len(self.decisions), self.plan_name)
        self.client.bus.publish(channels.SUPERVISOR_DECISION, msg)
        self._record(channels.SUPERVISOR_DECISION, msg)
        self.decisions.append(d)
        return d

    def _record(self, channel: str, msg: Any) -> None:
        """Writes ``msg`` to the journal (when there is one), stamped with the controller's
        time."""
        if self._journal is not None:
            self._journal.write_event(self.client.utime(), channel, msg.encode())

    def emit(self, name: str, detail: str = "", value: float = 0.0) -> None:
        msg = event_message(self.client.utime(), name, SOURCE, detail, value)
        self.client.bus.publish(channels.SUPERVISOR_EVENT, msg)
        self.events.append((msg.utime, name, detail))

    def _set(self, state: str | None = None, status: str | None = None, detail: str = "") -> None:
        changed = False
        if state is not None and state != self.state:
            self.state, changed = state, True
        if status is not None and status != self.status:
            self.status, changed = status, True
        if detail != self.detail:
            self.detail, changed = detail, True
        if changed:
            self.publish_state()

    def publish_state(self) -> None:
        msg = lcmt_supervisor_state()
        msg.utime = self.client.utime()
        msg.plan_name = self.plan_name
        msg.state = self.state
        msg.step_index = self.step_index
        msg.num_steps = len(self.steps)
        msg.status = self.status
        msg.detail = self.detail
        self.client.bus.publish(channels.SUPERVISOR_STATE, msg)

    def _publisher(self) -> None:
        while not self._publish_stop.wait(0.1):
            self.publish_state()

    # ---- the FSM ----------------------------------------------------------------------------
    def run(self, first: int = 0) -> SupervisorResult:
        """Executes the steps from ``first`` on; never raises on an execution failure (the
        result says why), holds the robot when it fails."""
        self.prepare(first)
        records: list[StepRecord] = []
        if self.journal is not None:
            self._journal = lcm.EventLog(str(self.journal), "w", overwrite=True)
        publisher = threading.Thread(target=self._publisher, name="supervisor-state", daemon=True)
        publisher.start()
        # What is alive now (models, plan, references) lives until the end: the collector never
        # walks it again. Its full passes over that heap held the interpreter's lock for 60-320 ms
        # (more on a loaded machine) while the references had to be streamed and the heartbeat fed.
        gc.freeze()
        try:
            for step, spec in zip(self.steps[first:], self.specs[first:]):
                record = StepRecord(step.index, step.transition, step.kind)
                records.append(record)
                self.step_index = step.index
                self._run_step(step, spec, record)
            self._set("done", "finished", f"{len(records)} steps")
            self.emit("done", f"{len(records)} steps")
            return SupervisorResult(True, "done", "", records, self.events)
        except SupervisorFailure as failure:
            if records:
                records[-1].result = str(failure)
            self.client.send_command("hold", SOURCE, str(failure))
            self.emit(failure.event, failure.detail)
            self._set("failed", "holding", str(failure))
            return SupervisorResult(False, "failed", str(failure), records, self.events)
        finally:
            gc.unfreeze()  # a process that goes on (a campaign's) collects them again
            self._publish_stop.set()
            publisher.join(timeout=1.0)
            self.publish_state()
            if self._journal is not None:
                self._journal.close()
                self._journal = None

    def _run_step(self, step: Step, spec: ControllerSpec, record: StepRecord) -> None:
        o = self.options
        wall0 = time.monotonic()
        self._set(step.transition, "awaiting_approval" if o.step_mode else "starting")
        cid = self._next_id
        self._next_id += 1
        record.controller_id = cid
        thresholds = {t.name: END_THRESHOLDS.get(t.kind, 0.01) for t in spec.tasks}
        if self.servo is not None:
            thresholds = self.servo.end_thresholds(step, spec, thresholds)
        traj = self.trajectories[step.index]
        record.retimed, record.retimed_for = traj.retimed, traj.retimed_for
        record.lean = traj.lean
        self._decided(
            self.machine.begin_step(
                step.index,
                step.transition,
                cid,
                thresholds,
                int(o.converge_timeout_s * 1e6),
                o.step_mode,
                self._rest(step, spec),
            )
        )
        if o.step_mode:
            self._drive(
                record,
                ("approved",),
                None,
                o.approval_timeout_s,
                "approval_timeout",
                "no 'approve' within {} s",
            )
        self.emit("step_started", f"{step.index} {step.transition}")
        for gripper, handle in step.released.items():
            self._weld("detach", gripper, handle)
            record.events.append(f"released {gripper}")

        # Start check: the controller swaps the spec in only without a command jump; a refused
        # swap is sent again once the previous controller is at rest (decisions.py).
        self._set(status="waiting_start_check", detail=f"controller {cid}")
        self.client.send_spec(dataclasses.replace(spec, controller_id=cid))
        while (
            self._drive(
                record,
                ("switch_accepted", "switch_resend"),
                None,
                o.accept_timeout_s,
                "switch_timeout",
                f"no decision on the swap to controller {cid} within {{}} s",
            ).event
            == "switch_resend"
        ):
            cid = self._next_id
            self._next_id += 1
            record.controller_id = cid
            record.switch_retries += 1
            self._decided(self.machine.resend_switch(cid))
            self._set(status="waiting_start_check", detail=f"controller {cid} (sent again)")
            self.client.send_spec(dataclasses.replace(spec, controller_id=cid))
        record.utime_start = self.client.utime()
        self.emit("switch_accepted", f"controller {cid} {spec.name}")

        # Streaming.
        start = self.client.utime() + o.start_delay_us
        # Visual servoing (execution.visual_servo): the streamer corrects the pbvs tasks and
        # re-sends what it already streamed of them when a measurement arrives.
        corrections = self.servo.begin_step(step, spec, start, o.dt_us) if self.servo else []
        streamer = ReferenceStreamer(
            self.client.send_reference,
            cid,
            traj.references,
            start,
            o.dt_us,
            o.chunk_samples,
            o.lookahead_s,
            corrections=corrections,
            servo=self.servo,
        )
        self._decided(self.machine.start_reference(start, streamer.end_utime))
        record.utime_reference_start = start
        record.duration_s = traj.duration
        self._set(status="running")
        self._drive(record, ("end_of_reference",), streamer)
        record.utime_reference_end = streamer.end_utime
        if self.servo is not None:
            self.servo.end_step(corrections)
        record.chunks = streamer.chunks_sent
        record.min_lookahead_ms = (
            None if streamer.min_margin_us is None else streamer.min_margin_us / 1e3
        )
        self.emit("end_of_reference", f"{step.index} {step.transition}")

        # End check: every task error converged (decided on the statuses after the last sample).
        self._set(status="waiting_end_check")
        self._drive(record, ("end_check_passed",), None)
        record.utime_end = self.client.utime()

        for gripper, handle in step.created.items():
            self._weld("attach", gripper, handle)
            record.events.append(f"grasped {gripper}")
        record.wall_s = time.monotonic() - wall0
        record.result = "ok"
        self.emit("step_done", f"{step.index} {step.transition}")

    def _rest(self, step: Step, spec: ControllerSpec) -> StepRest:
        """The command bounds of ``step``'s switch and end check (decisions.StepRest): its own
        and the next controller's jump bounds, the joints an admittance task ramps in either."""
        if not self.options.rest_checks:
            return StepRest()
        nxt = self.specs[step.index + 1] if step.index + 1 < len(self.specs) else None
        ramped = {
            j
            for s in (spec, nxt)
            if s is not None
            for t in s.tasks
            if t.kind == "gripper_admittance"
            for j in t.joints
        }
        return StepRest(
            spec.max_switch_velocity_jump,
            float("inf") if nxt is None else nxt.max_switch_velocity_jump,
            self.options.switch_retries,
            int(self.options.settle_timeout_s * 1e6),
            tuple(sorted(ramped)),
        )

    def _drive(
        self,
        record: StepRecord,
        until: tuple[str, ...],
        streamer: ReferenceStreamer | None,
        timeout_s: float | None = None,
        timeout_event: str = "",
        timeout_detail: str = "",
    ) -> Decision:
        """Feeds the received messages to the decision machine one at a time (streaming the
        references as the controller's clock advances) until it takes a decision in ``until``;
        raises SupervisorFailure on a failure decision. A wall-clock timeout is itself an input
        (a TIMER decision)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            # One status can decide twice (the end of the reference and the end check): a
            # decision is published and acted on when taken, and awaited from this list.
            while self._taken:
                d = self._taken.pop(0)
                if d.event in until:
                    return d
            if self.machine.status in ("ended", "failed"):
                raise RuntimeError(
                    f"supervisor: the step ended ({self.machine.status}) without {until}"
                )
            now = self.client.utime()
            if streamer is not None:
                streamer.pump(now)
                if streamer.done and not self.machine.reference_sent:
                    self._decided(self.machine.reference_end(streamer.end_utime, True))
            while (item := self._next_input()) is not None:
                channel, msg = item
                if channel == decisions.STATUS:
                    self._fold_status(record, msg)
                elif channel == decisions.EVENT:
                    record.events.append(msg.name)
                self._record(channel, msg)  # decisions.STATUS etc. are the channels' names
                for d in self.machine.feed(channel, msg):
                    self._taken.append(d)
                    self._act(self._decided(d), record, streamer, msg)
                if self._taken:
                    break
            if self._taken:
                continue
            if deadline is not None and time.monotonic() > deadline:
                d = self._decided(
                    self.machine.timeout(timeout_event, timeout_detail.format(timeout_s))
                )
                raise SupervisorFailure(d.event, d.detail)
            self.client.wait(
                self._later_or_input(now),
                5.0,
                "controller time to advance",
            )

    def _act(
        self, d: Decision, record: StepRecord, streamer: ReferenceStreamer | None, msg: Any
    ) -> None:
        """What the supervisor does on a decision besides publishing it."""
        if d.event.startswith("end_check_"):
            record.final_errors = dict(zip(msg.task_name, msg.task_error_norm))
        if d.event in decisions.FAILURES:
            raise SupervisorFailure(d.event, d.detail)
        if d.event == "switch_retry":
            record.events.append(f"switch refused, retried: {d.detail}")
            self.emit("switch_retry", d.detail)
        if d.event == "reference_stopped" and streamer is not None:
            streamer.stop_early(self.client.utime())
            self.emit("reference_stopped", d.detail, msg.value)
            self._decided(self.machine.reference_end(streamer.end_utime, True))

    def _fold_status(self, record: StepRecord, st: Any) -> None:
        """The step's task errors, for the report (not a decision)."""
        if st.active_controller_id == record.controller_id and self.machine.status in (
            "running",
            "waiting_end_check",
        ):
            errors = dict(zip(st.task_name, st.task_error_norm))
            record.error_trace.append((st.utime, errors))
            for n, e in errors.items():
                record.max_errors[n] = max(record.max_errors.get(n, 0.0), e)

    def _weld(self, action: str, gripper: str, handle: str) -> None:
        obj = handle.split("/")[0]
        weld = f"grasp/{gripper}/{obj}"
        if self.options.simulated_grasps:
            (self.client.attach if action == "attach" else self.client.detach)(weld)
        self.emit("grasp" if action == "attach" else "release", weld)
