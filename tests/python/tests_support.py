"""Small helpers for tests that drive processes."""

from __future__ import annotations

import select
import time
from typing import IO


def wait_for_line(stream: IO[str], needle: str, timeout_s: float) -> str | None:
    """Read ``stream`` line by line until one contains ``needle``; None on timeout or EOF."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([stream], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            return None
        line = stream.readline()
        if not line:
            return None
        if needle in line:
            return line
    return None
