"""Signed command messages — the Python twin of cpp/include/marionette/lcm/signing.h (the wire
format is in lcmtypes/README.md, "Signed messages"): with a shared key, the messages of the
command channels (:data:`marionette.channels.SIGNED`) carry a 52-byte trailer after their LCM
encoding — magic ``MSIG``, an 8-byte sender id, an 8-byte sequence (the sender's wall clock in
microseconds, strictly increasing) and HMAC-SHA256(key, domain NUL channel NUL message sender
sequence) from the standard library's ``hmac``/``hashlib``.

The key is a file (``MARIONETTE_KEY`` names it) of at least 32 bytes readable by its owner only:

    openssl rand -hex 32 > ~/.marionette-key && chmod 600 ~/.marionette-key
"""

from __future__ import annotations

import hashlib
import hmac
import os
import stat
import struct
import threading
import time
from pathlib import Path

from marionette import channels

# The command channels: signed with a key (lcmtypes/CHANNELS.md, column "signed").
SIGNED_CHANNELS = frozenset(
    {
        channels.CONTROLLER_SPEC,
        channels.TASK_REFERENCE,
        channels.COMMAND,
        channels.SIM_COMMAND,
        channels.FOOTSTEP_PLAN,
        channels.DG_REQUEST,
    }
)
TRAILER_SIZE = 52
MAGIC = b"MSIG"
DOMAIN = b"marionette-lcm-signature-v1\0"
WINDOW_S = 10.0  # a sequence further than this from the receiver's clock is refused
MIN_KEY_BYTES = 32
MAX_SENDERS = 4096

# The reasons, as the controller counts them (wire::ToString).
UNSIGNED = "unsigned"
BAD_SIGNATURE = "bad signature"
REPLAYED = "replayed"
STALE = "stale signature"
SIGNED_NO_KEY = "signed, no key"


class KeyFileError(ValueError):
    """The key file is missing, too short or readable by others; the message says what to do."""


def load_key(path: str | os.PathLike) -> bytes:
    """The shared key: the file's bytes, trailing whitespace removed."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except OSError:
        raise KeyFileError(
            f"key file {str(path)!r} not found "
            "(create one: openssl rand -hex 32 > FILE; chmod 600 FILE)"
        ) from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise KeyFileError(
            f"key file {str(path)!r} is readable by others: chmod 600 it (a shared key is a secret)"
        )
    key = path.read_bytes().rstrip()
    if len(key) < MIN_KEY_BYTES:
        raise KeyFileError(
            f"key file {str(path)!r} holds {len(key)} bytes, at least {MIN_KEY_BYTES} are needed "
            "(openssl rand -hex 32 > FILE)"
        )
    return key


def key_from_environment() -> bytes | None:
    """The key named by ``$MARIONETTE_KEY``, None when it is not set."""
    path = os.environ.get("MARIONETTE_KEY")
    return load_key(path) if path else None


def _tag(key: bytes, channel: str, message: bytes, sender_and_sequence: bytes) -> bytes:
    mac = hmac.new(key, DOMAIN, hashlib.sha256)
    mac.update(channel.encode() + b"\0")
    mac.update(message)
    mac.update(sender_and_sequence)
    return mac.digest()


def has_trailer(data: bytes) -> bool:
    return len(data) >= TRAILER_SIZE and bytes(data[-TRAILER_SIZE : -TRAILER_SIZE + 4]) == MAGIC


class Signer:
    """Appends the trailer; one sender id per Signer (thread-safe)."""

    def __init__(self, key: bytes) -> None:
        self.key = key
        self.sender = os.urandom(8)
        self._last = 0
        self._lock = threading.Lock()

    def sign(self, channel: str, message: bytes, now_us: int | None = None) -> bytes:
        with self._lock:
            now = int(time.time() * 1e6) if now_us is None else int(now_us)
            self._last = max(self._last + 1, now)
            head = self.sender + struct.pack(">Q", self._last)
        return message + MAGIC + head + _tag(self.key, channel, message, head)


class Verifier:
    """Checks trailers as the controller does: tag, freshness, replays per (sender, channel)."""

    def __init__(self, key: bytes, window_s: float = WINDOW_S) -> None:
        self.key = key
        self.window_s = window_s
        self._last: dict[tuple[bytes, str], int] = {}
        self._lock = threading.Lock()

    def verify(
        self, channel: str, data: bytes, now_us: int | None = None
    ) -> tuple[bytes | None, str, str]:
        """(message, "", "") when accepted, else (None, reason, detail)."""
        if not has_trailer(data):
            return None, UNSIGNED, "no signature, and this process takes signed messages only"
        message, trailer = bytes(data[:-TRAILER_SIZE]), bytes(data[-TRAILER_SIZE:])
        head, tag = trailer[4:20], trailer[20:]
        if not hmac.compare_digest(_tag(self.key, channel, message, head), tag):
            return (
                None,
                BAD_SIGNATURE,
                "the tag does not match (another key, altered bytes, or another channel)",
            )
        sender, (sequence,) = head[:8], struct.unpack(">Q", head[8:])
        now = int(time.time() * 1e6) if now_us is None else int(now_us)
        skew = (sequence - now) * 1e-6
        if abs(skew) > self.window_s:
            return (
                None,
                STALE,
                f"signed {abs(skew):.1f} s {'before' if skew < 0 else 'after'} this clock (at "
                f"most {self.window_s:.0f} s: replayed, or the clocks of the machines disagree)",
            )
        with self._lock:
            last = self._last.get((sender, channel))
            if last is not None and sequence <= last:
                return None, REPLAYED, f"sequence {sequence} after {last} from the same sender"
            if last is None and len(self._last) >= MAX_SENDERS:
                del self._last[min(self._last, key=self._last.__getitem__)]
            self._last[(sender, channel)] = sequence
        return message, "", ""
