"""Streams a step's task references to marionette-controller on TASK_REFERENCE, ahead of the
controller's clock, so that the watchdog (which holds the robot when a stream runs dry) never
fires in a nominal run.

Chunks of ``chunk_samples`` samples are sent while their start time is less than
``lookahead_s`` ahead of the controller's latest time; the controller keeps up to 5 s of samples
per stream (ReferenceStream's capacity), so the look-ahead must stay well under that. The last
chunk of each task carries ``last_chunk`` ("end of reference", §3.2.5.2): the stream then holds
its final value and the watchdog ignores it. The chunks of each task are numbered (``sequence``):
the controller refuses a chunk whose predecessor it never took, so a chunk lost on the way holds
the robot instead of letting it jump ahead along its plan.

Visual servoing (:mod:`.visual_servo`): with ``corrections`` the pose rows of those tasks are
right-multiplied by their current correction when sent, and when a correction changes the
samples already sent from ``now + lead`` on are sent again (a chunk replaces the stream's
future from its start, ReferenceStream), so a new measurement acts within ``lead``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from marionette.control.spec import reference_chunk

if TYPE_CHECKING:
    from marionette.control.client import ControllerClient

MAX_LOOKAHEAD_S = 4.0  # ReferenceStream keeps 5 s of samples


class ReferenceStreamer:
    """Sends ``references`` (task -> (values N x k, derivatives N x m)) of one controller from
    controller time ``start_utime``, sample period ``dt_us``; call :meth:`pump` with the
    controller's time as often as it advances."""

    def __init__(
        self,
        send: Callable[[object], None],
        controller_id: int,
        references: dict[str, tuple[np.ndarray, np.ndarray]],
        start_utime: int,
        dt_us: int = 1000,
        chunk_samples: int = 200,
        lookahead_s: float = 1.0,
        max_chunks_per_pump: int = 4,
        corrections: list | None = None,
        servo=None,
    ) -> None:
        if not references:
            raise ValueError("nothing to stream")
        sizes = {len(v) for v, _ in references.values()}
        if len(sizes) != 1:
            raise ValueError(f"references of different lengths {sorted(sizes)}")
        if not 0.0 < lookahead_s <= MAX_LOOKAHEAD_S:
            raise ValueError(f"lookahead_s must be in (0, {MAX_LOOKAHEAD_S}], got {lookahead_s}")
        if not 1 <= chunk_samples <= 1000:
            raise ValueError(
                f"chunk_samples must be in [1, 1000] (the controller's chunk size), "
                f"got {chunk_samples}"
            )
        self.send = send
        self.controller_id = controller_id
        self.references = references
        self.start_utime = int(start_utime)
        self.dt_us = int(dt_us)
        self.chunk_samples = chunk_samples
        self.lookahead_us = int(lookahead_s * 1e6)
        self.max_chunks_per_pump = max_chunks_per_pump
        self.num_samples = sizes.pop()
        self.next_sample = 0
        self.chunks_sent = 0
        self.min_margin_us: int | None = None  # smallest lead of the stream over the clock seen
        self.stopped_at: int | None = None
        self.corrections = {c.task: c for c in corrections or []}
        self.servo = servo
        self._sent_versions: dict[str, int] = {}
        self._last_refresh_us = -(1 << 62)
        self._sequence = dict.fromkeys(references, 0)  # the next chunk's number, per task

    def _send(
        self, task: str, k0: int, values: np.ndarray, derivatives: np.ndarray, last: bool
    ) -> None:
        """Sends ``values`` as the task's next chunk, from sample ``k0``."""
        self.send(self._chunk(task, k0, values, derivatives, last))

    def _chunk(
        self, task: str, k0: int, values: np.ndarray, derivatives: np.ndarray, last: bool
    ) -> object:
        """The task's next chunk (numbered), ``values`` from sample ``k0``."""
        chunk = reference_chunk(
            self.controller_id,
            task,
            self.start_utime + k0 * self.dt_us,
            values,
            derivatives,
            self.dt_us,
            last,
            self._sequence[task],
        )
        self._sequence[task] += 1
        return chunk

    @property
    def end_utime(self) -> int:
        """Controller time of the last sample (the one held after :meth:`stop_early`)."""
        last = self.num_samples - 1 if self.stopped_at is None else self.stopped_at
        return self.start_utime + last * self.dt_us

    @property
    def done(self) -> bool:
        return self.next_sample >= self.num_samples

    def pump(self, now_utime: int) -> int:
        """Sends the chunks due before ``now + lookahead``, at most ``max_chunks_per_pump`` of
        them (a burst of large UDP datagrams overflows the receiver's socket buffer and LCM
        drops them); returns the number sent."""
        if not self.done:
            margin = self.start_utime + self.next_sample * self.dt_us - now_utime
            if self.next_sample > 0:
                self.min_margin_us = (
                    margin if self.min_margin_us is None else min(self.min_margin_us, margin)
                )
        sent = 0
        while (
            not self.done
            and sent < self.max_chunks_per_pump
            and self.start_utime + self.next_sample * self.dt_us < now_utime + self.lookahead_us
        ):
            k0 = self.next_sample
            k1 = min(k0 + self.chunk_samples, self.num_samples)
            last = k1 >= self.num_samples
            for task, (_values, _derivatives) in self.references.items():
                self._send(task, k0, *self._corrected(task, k0, k1), last)
            self.next_sample = k1
            self.chunks_sent += 1
            sent += 1
        if self.servo is not None and self.stopped_at is None:
            self._refresh(now_utime)
        return sent

    def _corrected(self, task: str, k0: int, k1: int) -> tuple[np.ndarray, np.ndarray]:
        values, derivatives = self.references[task]
        c = self.corrections.get(task)
        if c is None:
            return values[k0:k1], derivatives[k0:k1]
        if not c.blend_out:
            return c.apply(values[k0:k1], derivatives[k0:k1], c.C)
        rows = [
            c.apply(values[k : k + 1], derivatives[k : k + 1], c.at_sample(k, self.dt_us))
            for k in range(k0, k1)
        ]
        return np.vstack([r[0] for r in rows]), np.vstack([r[1] for r in rows])

    def _refresh(self, now_utime: int) -> None:
        """Folds new measurements in (every step: the servo keeps what it sees of objects at
        rest); re-sends the corrected tasks' future already sent."""
        self.servo.update(self.references, self.dt_us, now_utime)
        if now_utime - self._last_refresh_us < self.servo.options.refresh_us:
            return
        stale = [
            t
            for t, c in self.corrections.items()
            if not c.blend_out and self._sent_versions.get(t, -1) != c.version
        ]
        if not stale:
            return
        self._last_refresh_us = now_utime
        k_from = max(0, (now_utime + self.servo.options.lead_us - self.start_utime) // self.dt_us)
        # A chunk replaces its stream's future from its start: until the next piece comes, the
        # first one cuts the stream at its own end. So every piece is made first, then they are
        # sent back to back. Made between two sends, they once left 0.45 s (wall) between two
        # pieces of a supervisor slowed down by a loaded machine: the stream ran dry and the
        # watchdog held the robot.
        chunks = []
        for task in stale:
            k0 = int(k_from)
            while k0 < self.next_sample:
                k1 = min(k0 + 1000, self.next_sample)
                values, derivatives = self._corrected(task, k0, k1)
                chunks.append(self._chunk(task, k0, values, derivatives, k1 >= self.num_samples))
                k0 = k1
            self._sent_versions[task] = self.corrections[task].version
        for chunk in chunks:
            self.send(chunk)

    def stop_early(self, now_utime: int, lead_us: int = 20_000) -> None:
        """Ends every reference at the sample due ``lead_us`` from now (a force event: the goal
        is reached before the plan says, §3.2.5.2): one last chunk holding that sample, never
        past what was already sent (a sample after a gap would start the stream afresh there)."""
        k = int(
            np.clip(
                (now_utime + lead_us - self.start_utime) // self.dt_us,
                0,
                max(min(self.next_sample, self.num_samples) - 1, 0),
            )
        )
        for task, (values, derivatives) in self.references.items():
            self._send(task, k, values[k : k + 1], np.zeros_like(derivatives[k : k + 1]), True)
        self.next_sample = self.num_samples
        self.stopped_at = k


def stream_to_end(
    client: ControllerClient,
    controller_id: int,
    references: dict[str, tuple[np.ndarray, np.ndarray]],
    lead_us: int = 100_000,
) -> ReferenceStreamer:
    """Streams ``references`` to controller ``controller_id`` from ``lead_us`` after the
    controller's time (defaults of :class:`ReferenceStreamer` otherwise), pumping as the clock
    advances, and returns once the clock has passed their last sample: a motion played to its
    end. The streamer tells what was sent (``chunks_sent``, ``min_margin_us``)."""
    streamer = ReferenceStreamer(
        client.send_reference, controller_id, references, client.utime() + lead_us
    )
    while not (streamer.done and client.utime() >= streamer.end_utime):
        now = client.utime()
        streamer.pump(now)
        client.wait_past(now, 5.0, "controller time to advance")
    return streamer
