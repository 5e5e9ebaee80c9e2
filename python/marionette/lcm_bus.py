"""LCM for marionette's Python processes: URL choice, typed subscriptions, a handling thread.

Every process takes its URL from ``--lcm-url`` or ``MARIONETTE_LCM_URL``; tests and demos make a
private one with :func:`private_lcm_url` so that concurrent runs never cross-talk. TTL 0 keeps
multicast on the machine.
"""

from __future__ import annotations

import os
import random
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import lcm

DEFAULT_LCM_URL = "udpm://239.255.76.67:7667?ttl=0"


def lcm_url(url: str | None = None) -> str:
    """The URL to use: ``url`` if given, else ``$MARIONETTE_LCM_URL``, else the default."""
    return url or os.environ.get("MARIONETTE_LCM_URL") or DEFAULT_LCM_URL


def private_lcm_url(rng: random.Random | None = None) -> str:
    """A loopback multicast URL on a random port (no traffic leaves the machine: ttl=0)."""
    port = (rng or random.SystemRandom()).randrange(20000, 60000)
    return f"udpm://239.255.76.67:{port}?ttl=0"


class LcmBus:
    """An LCM instance with typed subscriptions and an optional background handling thread.

    Messages that do not decode as the subscribed type are counted in ``decode_errors``
    (per channel) and dropped: a malformed message never reaches a handler.
    """

    def __init__(self, url: str | None = None) -> None:
        self.url = lcm_url(url)
        self.lcm = lcm.LCM(self.url)
        self.decode_errors: dict[str, int] = defaultdict(int)
        self._thread: threading.Thread | None = None
        self._running = False

    def publish(self, channel: str, message: Any) -> None:
        self.lcm.publish(channel, message.encode())

    def subscribe(self, channel: str, lcm_type: type, handler: Callable[[Any], None]):
        def _on_message(_channel: str, data: bytes) -> None:
            try:
                msg = lcm_type.decode(data)
            except ValueError:
                self.decode_errors[channel] += 1
                return
            handler(msg)

        return self.lcm.subscribe(channel, _on_message)

    def handle(self, timeout_s: float) -> bool:
        """Handle at most one message, waiting up to ``timeout_s``; True if one was handled."""
        return self.lcm.handle_timeout(int(timeout_s * 1000)) > 0

    def start(self) -> LcmBus:
        """Handle messages in a daemon thread until :meth:`stop`."""
        self._running = True
        self._thread = threading.Thread(target=self._loop, name="lcm-bus", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None

    def _loop(self) -> None:
        while self._running:
            self.lcm.handle_timeout(50)

    def __enter__(self) -> LcmBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class MessageLog:
    """Collects the messages of one channel (thread-safe); ``wait_for`` blocks until a condition."""

    def __init__(self, bus: LcmBus, channel: str, lcm_type: type) -> None:
        self.messages: list[Any] = []
        self._cond = threading.Condition()
        bus.subscribe(channel, lcm_type, self._append)

    def _append(self, msg: Any) -> None:
        with self._cond:
            self.messages.append(msg)
            self._cond.notify_all()

    def latest(self) -> Any | None:
        with self._cond:
            return self.messages[-1] if self.messages else None

    def wait_for(self, condition: Callable[[list[Any]], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not condition(self.messages):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(remaining)
            return True
