"""Small helpers for tests that drive processes."""

from __future__ import annotations

import contextlib
import select
import time
from pathlib import Path
from typing import IO, Iterator

from marionette.control.client import ControllerClient
from marionette.processes import ProcessGroup


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


@contextlib.contextmanager
def controller_running(build_dir: Path, lcm_url: str, log_dir: Path, *args: str, camera: bool = False,
                       ready_timeout: float = 60.0) -> Iterator[ControllerClient]:
    """Starts marionette-controller with ``args`` and yields a ready ControllerClient; the
    process is stopped afterwards and must exit cleanly."""
    binary = build_dir / "marionette-controller"
    with ProcessGroup(lcm_url, log_dir) as group, ControllerClient(lcm_url, camera=camera) as client:
        proc = group.start("controller", [binary, "--lcm-url", lcm_url, *args])
        try:
            client.wait_ready(ready_timeout)
        except TimeoutError:
            group.check_alive()
            raise
        client.process = proc
        client.group = group
        yield client
        group.check_alive()
        code = group.stop("controller", timeout_s=10.0)
        assert code == 0, f"controller exited with {code}:\n{proc.log_tail()}"
