"""Fixtures that run the real marionette-controller binary on the session's private LCM URL."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Iterator

import pytest

import marionette
from marionette.control.client import ControllerClient
from marionette.processes import ProcessGroup


@pytest.fixture
def run_controller(build_dir: Path, lcm_url: str, tmp_path: Path):
    """``with run_controller("--robot", "talos", ...) as client:`` starts the controller with
    those arguments and yields a ready ControllerClient; the process is stopped afterwards and
    must exit cleanly."""

    @contextlib.contextmanager
    def start(*args: str, camera: bool = False, ready_timeout: float = 60.0) -> Iterator[ControllerClient]:
        binary = build_dir / "marionette-controller"
        with ProcessGroup(lcm_url, tmp_path / "logs") as group, ControllerClient(lcm_url, camera=camera) as client:
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

    return start
