"""``marionette replay LOG --supervisor``: re-take the supervisor's decisions from a recorded run.

Reads the record of a run (:func:`decision_record`: the supervisor's own journal, else the LCM
log of the run, e.g. a demo's ``run.lcmlog``): the decisions published on SUPERVISOR_DECISION,
and the inputs the supervisor received, CONTROLLER_STATUS, ROBOT_COMMAND and the SUPERVISOR_EVENT
of other sources, in log order. A fresh :class:`decisions.DecisionMachine` is
fed those inputs (the recorded STEP/TIMER inputs re-fed at their ticks) and must take the same
decisions at the same ticks, having read the same values.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lcm
from marionette import (
    channels,
    lcmt_controller_status,
    lcmt_robot_command,
    lcmt_supervisor_decision,
    lcmt_supervisor_event,
)
from marionette.execution.decisions import (
    COMMAND,
    EVENT,
    STATUS,
    Decision,
    DecisionReplay,
    replay_decisions,
)
from marionette.execution.supervisor import JOURNAL_NAME, SOURCE


class DecisionLogError(ValueError):
    """The log cannot be replayed (no decisions, several supervisor runs, undecodable)."""


def read_decision_log(log: Path) -> tuple[list[Decision], list[tuple[str, Any]]]:
    """The recorded decisions (in ``seq`` order) and the supervisor's inputs in log order."""
    log = Path(log)
    if not log.is_file():
        raise FileNotFoundError(f"no LCM log at {log}")
    recorded: list[Any] = []
    inputs: list[tuple[str, Any]] = []
    try:
        events = lcm.EventLog(str(log), "r")
    except (OSError, ValueError) as e:
        raise DecisionLogError(f"{log} is not an LCM log: {e}") from None
    for ev in events:
        try:
            if ev.channel == channels.SUPERVISOR_DECISION:
                recorded.append(lcmt_supervisor_decision.decode(ev.data))
            elif ev.channel == channels.CONTROLLER_STATUS:
                inputs.append((STATUS, lcmt_controller_status.decode(ev.data)))
            elif ev.channel == channels.ROBOT_COMMAND:
                inputs.append((COMMAND, lcmt_robot_command.decode(ev.data)))
            elif ev.channel == channels.SUPERVISOR_EVENT:
                msg = lcmt_supervisor_event.decode(ev.data)
                if msg.source != SOURCE:  # the supervisor does not read its own events
                    inputs.append((EVENT, msg))
        except ValueError as e:
            raise DecisionLogError(
                f"{log}: cannot decode a {ev.channel} message at {ev.timestamp} us: {e}"
            ) from None
    if not recorded:
        raise DecisionLogError(
            f"{log} holds no {channels.SUPERVISOR_DECISION} message (a run recorded "
            "before the supervisor published its decisions, or no supervisor ran)"
        )
    recorded.sort(key=lambda m: m.seq)
    seqs = [m.seq for m in recorded]
    if seqs != list(range(len(seqs))):
        runs = sorted({m.plan_name for m in recorded})
        raise DecisionLogError(
            f"{log}: decision numbers are not 0..{len(seqs) - 1} (several supervisor "
            f"runs, plans {runs}, or lost messages): cannot replay"
        )
    return [Decision.from_lcm(m) for m in recorded], inputs


def decision_record(log: Path) -> Path:
    """What to replay for the run recorded in ``log``: the supervisor's journal beside it when
    there is one (every input it fed its machine, in that order, and every decision: a network
    logger may drop a message, and then the run cannot be replayed from its log), else ``log``."""
    journal = Path(log).parent / JOURNAL_NAME
    return journal if journal.is_file() else Path(log)


def replay_supervisor(log: Path) -> DecisionReplay:
    """Replays the decisions of the supervisor run recorded in ``log`` (a run's LCM log or the
    supervisor's journal: replay what :func:`decision_record` says)."""
    recorded, inputs = read_decision_log(log)
    return replay_decisions(recorded, inputs)


def format_verdict(log: Path, r: DecisionReplay) -> str:
    head = (
        f"supervisor replay of {log}: {r.recorded} decisions recorded, {r.replayed} re-taken from "
        f"{r.statuses} CONTROLLER_STATUS and {r.events} SUPERVISOR_EVENT messages"
    )
    if r.ok:
        return f"{head}\nIDENTICAL: same decisions at the same ticks from the same inputs\n"
    return f"{head}\nDIVERGED: first divergence: {r.first_divergence}\n"
