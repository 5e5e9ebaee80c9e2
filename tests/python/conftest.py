"""Fixtures shared by the whole Python suite."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

import marionette
from marionette.lcm_bus import private_lcm_url


@pytest.fixture(scope="session")
def build_dir() -> Path:
    path = marionette.BUILD_DIR
    if not (path / "CMakeCache.txt").exists():
        pytest.fail(f"no C++ build in {path}: run `make test` (or scripts/setup) first")
    return path


@pytest.fixture(scope="session")
def lcm_url() -> str:
    """A private loopback multicast URL for this test session (random port, ttl=0)."""
    return private_lcm_url()


@pytest.fixture
def lcm_env(lcm_url: str) -> dict[str, str]:
    """Environment for child processes: the session's LCM URL and the build directory."""
    env = dict(os.environ)
    env["MARIONETTE_LCM_URL"] = lcm_url
    env["MARIONETTE_BUILD_DIR"] = str(marionette.BUILD_DIR)
    return env


def require_program(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.fail(f"{name} not found: scripts/setup installs it")
    return path
