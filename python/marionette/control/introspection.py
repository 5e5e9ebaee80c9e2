"""The running controller's graph from any machine on the LCM network (DG_REQUEST / DG_REPLY /
DG_TRACE): list it, read and set signals, trace them, draw it, read per-entity timing; and its
health from CONTROLLER_STATUS (:func:`read_status`, :func:`status_text`: mode, why, and every
refused input counted per channel and reason).

    client = GraphClient(url)
    print(client.ls())
    q = client.get("robot.configuration")["robot.configuration"]
    client.set("c3_posture.gain", 5.0)            # only inputs declared settable
    for sample in client.trace(["safety.command"], rate=100, duration=2.0): ...
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from marionette import channels, lcmt_controller_status, lcmt_dg_reply, lcmt_dg_request
from marionette.lcm_bus import LcmBus, MessageLog


class IntrospectionError(RuntimeError):
    """The controller refused the request (the message says why) or did not answer."""


@dataclass
class TraceSample:
    tick: int
    utime: int
    values: dict[str, np.ndarray]


def reply_values(reply) -> dict[str, np.ndarray]:
    """The values of a reply, each reshaped (column-major) to its signal's shape: scalars as
    0-d arrays, vectors as 1-d, matrices and SE3 as 2-d."""
    out, offset = {}, 0
    for name, rows, cols in zip(reply.signal, reply.rows, reply.cols):
        flat = np.array(reply.value[offset : offset + rows * cols])
        offset += rows * cols
        out[name] = (
            flat.reshape((rows, cols), order="F")
            if cols > 1
            else (flat if rows > 1 else flat.reshape(()))
        )
    return out


class GraphClient:
    def __init__(self, lcm_url: str | None = None, timeout_s: float = 5.0) -> None:
        self.bus = LcmBus(lcm_url)
        self.timeout_s = timeout_s
        self.client = f"{os.uname().nodename}:{os.getpid()}:{id(self):x}"
        self._ids = itertools.count(int(time.time() * 1000) % 1_000_000 * 1000)
        self._cond = threading.Condition()
        self._replies: dict[int, Any] = {}  # lcmt_dg_reply by request id
        self._trace: list[Any] = []  # lcmt_dg_reply
        self.bus.subscribe(channels.DG_REPLY, lcmt_dg_reply, self._on_reply)
        # LCM drops a subscription's messages beyond its queue (30 by default) while the handling
        # thread is off the CPU: 10 s of a 1 kHz trace may wait here.
        self.bus.subscribe(channels.DG_TRACE, lcmt_dg_reply, self._on_trace).set_queue_capacity(
            10_000
        )
        self.bus.start()

    def close(self) -> None:
        self.bus.stop()

    def __enter__(self) -> GraphClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _on_reply(self, reply) -> None:
        if reply.client != self.client:
            return
        with self._cond:
            self._replies[reply.request_id] = reply
            self._cond.notify_all()

    def _on_trace(self, reply) -> None:
        if reply.client != self.client:
            return
        with self._cond:
            self._trace.append(reply)
            self._cond.notify_all()

    def request(
        self,
        command: str,
        signals: Sequence[str] = (),
        values: Iterable[float] = (),
        rate: float = 0.0,
    ):
        """Sends a request and waits for its reply; raises IntrospectionError on refusal."""
        msg = lcmt_dg_request()
        msg.utime = int(time.time() * 1e6)
        msg.request_id = next(self._ids)
        msg.client = self.client
        msg.command = command
        msg.signal = list(signals)
        msg.num_signals = len(msg.signal)
        msg.value = [float(v) for v in values]
        msg.num_values = len(msg.value)
        msg.rate = float(rate)
        deadline = time.monotonic() + self.timeout_s
        with self._cond:
            self.bus.publish(channels.DG_REQUEST, msg)
            while msg.request_id not in self._replies:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise IntrospectionError(
                        f"no reply to {command!r} from marionette-controller within "
                        f"{self.timeout_s} s (is it running on {self.bus.url}?)"
                    )
                self._cond.wait(remaining)
            reply = self._replies.pop(msg.request_id)
        if not reply.ok:
            raise IntrospectionError(f"{command} refused: {reply.error}")
        return reply

    def ls(self) -> str:
        return self.request("ls").text

    def dot(self) -> str:
        return self.request("graph").text

    def timing(self) -> str:
        return self.request("timing").text

    def budget(self, entity: str, budget_us: float) -> str:
        return self.request("budget", [entity], [budget_us]).text

    def get(self, *signals: str) -> dict[str, np.ndarray]:
        reply = self.request("get", signals)
        return reply_values(reply)

    def get_with_tick(self, *signals: str) -> tuple[int, dict[str, np.ndarray]]:
        reply = self.request("get", signals)
        return reply.tick, reply_values(reply)

    def set(self, signal: str, value) -> None:
        values = np.asarray(value, dtype=float).flatten(order="F")
        self.request("set", [signal], values)

    def trace(self, signals: Sequence[str], rate: float, duration: float) -> Iterator[TraceSample]:
        """Streams the signals at ``rate`` Hz for ``duration`` seconds (wall clock)."""
        with self._cond:
            self._trace.clear()
        self.request("trace", signals, rate=rate)
        end = time.monotonic() + duration
        try:
            while True:
                with self._cond:
                    while not self._trace and time.monotonic() < end:
                        self._cond.wait(0.05)
                    batch, self._trace = self._trace, []
                for reply in batch:
                    yield TraceSample(reply.tick, reply.utime, reply_values(reply))
                if time.monotonic() >= end:
                    return
        finally:
            try:
                self.request("untrace")
            except IntrospectionError:
                pass


def read_status(lcm_url: str | None = None, timeout_s: float = 5.0):
    """The next CONTROLLER_STATUS; raises IntrospectionError when none comes in time."""
    with LcmBus(lcm_url) as bus:
        log = MessageLog(bus, channels.CONTROLLER_STATUS, lcmt_controller_status)
        bus.start()
        if not log.wait_for(lambda m: len(m) > 0, timeout_s):
            raise IntrospectionError(
                f"no CONTROLLER_STATUS within {timeout_s} s (is marionette-controller running on "
                f"{bus.url}?)"
            )
        return log.latest()


def rejections_by_channel(status) -> dict[str, dict[str, int]]:
    """channel -> reason -> count, from a status's "CHANNEL: reason" counters."""
    out: dict[str, dict[str, int]] = {}
    for key, count in zip(status.rejection_reason, status.rejection_count):
        channel, _, reason = key.partition(": ")
        out.setdefault(channel, {})[reason or "?"] = int(count)
    return out


def status_text(status) -> str:
    """The controller's mode and why, its active controller, and its refused inputs per channel
    and reason, as ``marionette dg status`` prints them."""
    lines = [
        f"{status.robot_name}: {status.mode} ({status.mode_reason})",
        f"active controller: {status.active_controller or '-'} (id {status.active_controller_id}); "
        f"{status.num_switches} switches, {status.num_refused_switches} refused",
        f"loop: lateness p99 {status.lateness.p99_us:.1f} us, {status.deadline_misses} deadline "
        "misses",
        f"refused inputs: {status.num_rejected}",
    ]
    for channel, reasons in sorted(rejections_by_channel(status).items()):
        lines.append(f"  {channel:22s} {sum(reasons.values()):9d}")
        for reason, count in sorted(reasons.items(), key=lambda rc: -rc[1]):
            lines.append(f"    {count:9d}  {reason}")
    if status.last_rejection:
        lines.append(f"last: {status.last_rejection}")
    return "\n".join(lines) + "\n"
