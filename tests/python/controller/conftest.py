"""Fixtures that run the real marionette-controller binary on the session's private LCM URL."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests_support import controller_running


@pytest.fixture
def run_controller(build_dir: Path, lcm_url: str, tmp_path: Path):
    """``with run_controller("--robot", "talos", ...) as client:`` (see controller_running)."""

    def start(*args: str, camera: bool = False, ready_timeout: float = 60.0):
        return controller_running(
            build_dir, lcm_url, tmp_path / "logs", *args, camera=camera, ready_timeout=ready_timeout
        )

    return start
