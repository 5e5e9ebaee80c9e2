"""The supervisor's running step, as the processes beside it see it: from SUPERVISOR_STATE.

:class:`StepFollower` turns each ``lcmt_supervisor_state`` into the step that runs (None when
none does: idle, done, failed, or an index the follower's steps do not have) and calls its
``on_step`` when that changes. The execution and grip monitors follow the plan with it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from marionette.execution.plan_steps import Step

NOT_RUNNING = ("idle", "done", "failed")


class StepFollower:
    def __init__(self, steps: list[Step], on_step: Callable[[Step | None], None]) -> None:
        self.steps = {s.index: s for s in steps}
        self.on_step = on_step
        self.index: int | None = None

    def on_supervisor_state(self, msg: Any) -> None:
        index = msg.step_index if msg.state not in NOT_RUNNING else None
        if index != self.index:
            self.index = index
            self.on_step(self.steps.get(index) if index is not None else None)
