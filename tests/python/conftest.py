"""Fixtures shared by the whole Python suite."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

import marionette
from marionette.lcm_bus import private_lcm_url


@pytest.fixture(scope="session", autouse=True)
def plan_cache_in_tmp(tmp_path_factory) -> Iterator[Path]:
    """Plans go to a temporary folder for the session (``MARIONETTE_PLAN_CACHE``, inherited by
    the demos the tests start), never to the checkout's reports/plans/cache."""
    from marionette.scenarios.plan_cache import CACHE_ENV

    before = os.environ.get(CACHE_ENV)
    path = tmp_path_factory.mktemp("plan-cache")
    os.environ[CACHE_ENV] = str(path)
    yield path
    if before is None:
        del os.environ[CACHE_ENV]
    else:
        os.environ[CACHE_ENV] = before


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


@pytest.fixture(scope="session")
def ur10_box_run(tmp_path_factory, lcm_url: str) -> Path:
    """One recorded `marionette demo ur10-box --speed 3 --view` run (≈ 30 s), shared by the replay
    and viewer tests: its report folder (run.lcmlog, report.json, logs/viewer.log, ...)."""
    import sys

    from tests_support import run_stopping_what_it_started

    out = tmp_path_factory.mktemp("ur10_box_run")
    env = dict(
        os.environ, MARIONETTE_LCM_URL=lcm_url, MARIONETTE_BUILD_DIR=str(marionette.BUILD_DIR)
    )
    proc = run_stopping_what_it_started(
        [
            sys.executable,
            "-m",
            "marionette.cli",
            "demo",
            "ur10-box",
            "--speed",
            "3",
            "--view",
            "--out",
            str(out),
        ],
        timeout_s=300,
        env=env,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (run,) = out.glob("ur10-box-*")
    return run


# Fixtures that run something long (a demo, a plan of the humanoid): a test that uses one is a long
# end-to-end run whatever its own body does, so it goes with the slow tests (`make test-fast`
# leaves it out) without each test having to say so.
LONG_FIXTURES = {"ur10_box_run", "talos_plank"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if LONG_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)


def pytest_sessionfinish(session, exitstatus):
    """An area with no test of the selected kind (``-m slow`` where none is slow) passes: ctest
    runs each area's quick and slow tests as two entries."""
    if exitstatus == pytest.ExitCode.NO_TESTS_COLLECTED:
        session.exitstatus = pytest.ExitCode.OK
