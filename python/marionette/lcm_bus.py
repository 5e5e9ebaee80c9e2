"""LCM for marionette's Python processes: URL choice, typed subscriptions, a handling thread,
and the boundary every message crosses.

Every process takes its URL from ``--lcm-url`` or ``MARIONETTE_LCM_URL``; tests and demos make a
private one with :func:`private_lcm_url` so that concurrent runs never cross-talk. TTL 0 keeps
multicast on the machine.

Received messages are checked against their type's declared bounds before they are decoded
(:mod:`marionette.lcm_validate`); a refused one is counted per channel and reason
(:attr:`LcmBus.refusals`), the first of each reported in one line, and never reaches a handler.
With a shared key (``MARIONETTE_KEY``, :mod:`marionette.lcm_signing`) the command channels'
messages are signed when sent and must be signed when received. A bus that sent a controller spec
drives the controller: from then on it sends the supervisor's heartbeat (COMMAND ``heartbeat``
every :data:`HEARTBEAT_PERIOD_S`) until it stops — the controller holds the robot when its
supervisor falls silent. The beats come from a C++ thread that never needs the interpreter's lock
(a Python thread starved by a long call elsewhere would silence a live supervisor), fed by a
Python thread: they stop :data:`HEARTBEAT_HANG_S` after this process's Python stops running.
"""

from __future__ import annotations

import os
import random
import socket
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any, Literal

import lcm
import marionette
from marionette import channels
from marionette import lcm_signing as signing
from marionette.lcm_validate import LcmType, validate

HEARTBEAT_PERIOD_S = 0.02  # five per 100 ms, the controller's default --supervisor-timeout
# The heartbeat is sent by a C++ thread (marionette._wire), heard even while another Python
# thread keeps the interpreter's lock, as long as this process's Python ran within this long: a
# supervisor that hangs falls silent after it (one that dies, at once).
HEARTBEAT_HANG_S = 1.0

DEFAULT_LCM_URL = "udpm://239.255.76.67:7667?ttl=0"


def lcm_url(url: str | None = None) -> str:
    """The URL to use: ``url`` if given, else ``$MARIONETTE_LCM_URL``, else the default."""
    return url or os.environ.get("MARIONETTE_LCM_URL") or DEFAULT_LCM_URL


def _ephemeral_port_floor() -> int:
    """The lowest port the kernel hands out to outgoing sockets (Linux: 32768)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def _bindable(port: int) -> bool:
    """Whether LCM can bind ``port`` (UDP, address reuse, as LCM binds it): a port another
    socket holds without reuse fails with "bind: Address already in use", and LCM then
    receives nothing at all."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("", port))
        except OSError:
            return False
    return True


def private_lcm_url(rng: random.Random | None = None) -> str:
    """A loopback multicast URL on a random free port (no traffic leaves the machine: ttl=0),
    below the kernel's ephemeral range so that an outgoing connection made later cannot take
    it (a test whose port another process held received no message: "bind: Address already in
    use")."""
    rng = rng or random.SystemRandom()
    top = max(_ephemeral_port_floor(), 21000)
    port = rng.randrange(20000, top)
    for _ in range(50):
        if _bindable(port):
            break
        port = rng.randrange(20000, top)
    return f"udpm://239.255.76.67:{port}?ttl=0"


def udp_receive_buffer_drops() -> int | None:
    """The datagrams the kernel has dropped so far, machine-wide, because a socket's receive
    buffer was full (``RcvbufErrors`` of /proc/net/snmp); None where it cannot be read. LCM
    loses the messages they carried: the difference over a run says whether its processes and
    its log missed any (``scripts/setup`` sizes the buffers)."""
    try:
        with open("/proc/net/snmp") as f:
            rows = [line.split() for line in f if line.startswith("Udp:")]
        return int(rows[1][rows[0].index("RcvbufErrors")])
    except (OSError, ValueError, IndexError):
        return None


def logger_command(url: str, log: str | os.PathLike, exclude: str | None = None) -> list[str]:
    """The command that writes every message on ``url`` to the LCM log ``log`` until SIGINT or
    SIGTERM: ``marionette-logger`` (cpp/apps/logger_main.cc; lcm-logger's file format, without
    the 30-message queue behind which lcm-logger drops messages on a busy machine). ``exclude``:
    a regex of channels left out (e.g. ``^CAMERA_``)."""
    command = [str(marionette.BUILD_DIR / "marionette-logger"), f"--lcm-url={url}", "-f", str(log)]
    return command + ([f"--exclude={exclude}"] if exclude else [])


class LcmBus:
    """An LCM instance with typed subscriptions and an optional background handling thread.

    A message refused on its way in (bounds, signature, decoding) is counted in ``refusals``
    ((channel, reason) -> count) and ``decode_errors`` (per channel) and dropped: it never
    reaches a handler. An exception raised by a handler is counted too (reason "handler error")
    and reported once: no exception leaves the handling thread. ``key``: the shared key of signed
    messages (default: ``$MARIONETTE_KEY``'s, None for none; ``False`` forces none).
    """

    def __init__(self, url: str | None = None, key: bytes | Literal[False] | None = None) -> None:
        self.url = lcm_url(url)
        self.lcm = lcm.LCM(self.url)
        if key is None:
            key = signing.key_from_environment()
        self.key: bytes | None = key or None
        self._signer = signing.Signer(self.key) if self.key else None
        self._verifier = signing.Verifier(self.key) if self.key else None
        self.decode_errors: dict[str, int] = defaultdict(int)
        self.refusals: dict[tuple[str, str], int] = defaultdict(int)
        self._thread: threading.Thread | None = None
        self._running = False
        self._heartbeat: threading.Thread | None = None
        self._heartbeat_stop = threading.Event()
        # The supervisor's heartbeat once this bus sent a spec (marionette._wire.Heartbeat).
        self.heartbeat: Any = None
        self.source = f"{os.path.basename(sys.argv[0]) or 'python'}:{os.getpid()}"

    def publish(self, channel: str, message: Any) -> None:
        data = message.encode()
        if self._signer is not None and channel in signing.SIGNED_CHANNELS:
            data = self._signer.sign(channel, data)
        self.lcm.publish(channel, data)
        if channel == channels.CONTROLLER_SPEC:
            self._start_heartbeat()

    def subscribe(
        self,
        channel: str,
        lcm_type: LcmType,
        handler: Callable[[Any], None],
        decode: Callable[[bytes], Any] | None = None,
    ):
        """Hands ``handler`` each ``lcm_type`` message of ``channel`` that passes the checks
        (signature, declared bounds), decoded by lcm-gen's Python decoder or by ``decode``
        (one with the same fields, e.g. arrays as numpy arrays)."""
        verifier = self._verifier if channel in signing.SIGNED_CHANNELS else None
        decoder = decode or lcm_type.decode

        def _on_message(_channel: str, data: bytes) -> None:
            if verifier is not None:
                verified, reason, detail = verifier.verify(channel, data)
                if verified is None:
                    self._refuse(channel, reason, detail)
                    return
                data = verified
            refusal = validate(lcm_type, data)
            if refusal is not None and refusal.reason == "trailing bytes":
                if signing.has_trailer(data):
                    self._refuse(
                        channel,
                        signing.SIGNED_NO_KEY,
                        "a signed message, and this process has no key (MARIONETTE_KEY)",
                    )
                    return
            if refusal is not None:
                self._refuse(channel, refusal.reason, refusal.detail)
                return
            try:
                msg = decoder(data)
            except Exception as exc:  # bounds passed: lcm-gen's decoder should not fail
                self._refuse(channel, "undecodable", repr(exc))
                return
            try:
                handler(msg)
            except Exception as exc:
                self._refuse(channel, "handler error", f"{type(exc).__name__}: {exc}")

        return self.lcm.subscribe(channel, _on_message)

    def _refuse(self, channel: str, reason: str, detail: str) -> None:
        self.decode_errors[channel] += 1
        self.refusals[(channel, reason)] += 1
        if self.refusals[(channel, reason)] == 1:
            print(
                f"lcm: refused a {channel} message ({reason}: {detail[:300]}); further ones are "
                "counted",
                file=sys.stderr,
                flush=True,
            )

    def _start_heartbeat(self) -> None:
        if self._heartbeat is not None:
            return
        from marionette._wire import Heartbeat

        self.heartbeat = Heartbeat(
            self.url, self.source, self.key or b"", HEARTBEAT_PERIOD_S, HEARTBEAT_HANG_S
        )
        self._heartbeat_stop.clear()
        self._heartbeat = threading.Thread(target=self._feed, name="lcm-heartbeat", daemon=True)
        self._heartbeat.start()

    def _feed(self) -> None:
        """Shows the C++ heartbeat thread that this process still runs Python."""
        assert self.heartbeat is not None
        while not self._heartbeat_stop.wait(HEARTBEAT_PERIOD_S):
            self.heartbeat.feed()

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
        """Stops the handling thread and the heartbeat (the controller then holds the robot after
        its --supervisor-timeout, unless another spec or heartbeat comes)."""
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        self._heartbeat_stop.set()
        if self._heartbeat is not None:
            self._heartbeat.join(timeout=1.0)
            self._heartbeat = None
        if self.heartbeat is not None:
            self.heartbeat.stop()

    def _loop(self) -> None:
        while self._running:
            self.lcm.handle_timeout(50)

    def __enter__(self) -> LcmBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class MessageLog:
    """Collects the messages of one channel (thread-safe); ``wait_for`` blocks until a condition."""

    def __init__(self, bus: LcmBus, channel: str, lcm_type: LcmType) -> None:
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
