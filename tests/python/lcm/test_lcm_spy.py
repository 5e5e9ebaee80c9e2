"""lcm-spy sees the project's types: its type database decodes a message a C++ process published,
and scripts/lcm-spy starts (under a virtual screen) with every project type found."""

from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest

import marionette
from tests_support import wait_for_line

ROOT = marionette.REPO_ROOT
NUM_TYPES = len(list((ROOT / "lcmtypes").glob("*.lcm")))


@pytest.mark.slow
def test_lcm_spy_type_database_decodes_cpp_messages(build_dir, lcm_url, tmp_path):
    jar = build_dir / "lcmtypes" / "marionette_lcmtypes.jar"
    classpath = f"{jar}:/usr/share/java/lcm.jar:{tmp_path}"
    subprocess.run(
        [
            "javac",
            "-nowarn",
            "-cp",
            classpath,
            "-d",
            str(tmp_path),
            str(ROOT / "tests/java/SpyDecode.java"),
        ],
        check=True,
        timeout=120,
    )
    spy = subprocess.Popen(
        ["java", "-Djava.net.preferIPv4Stack=true", "-cp", classpath, "SpyDecode", lcm_url, "8000"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_for_line(spy.stdout, "READY", timeout_s=30) is not None
        subprocess.run(
            [str(build_dir / "lcm_publish_messages"), lcm_url, "5"], check=True, timeout=30
        )
        out, _ = spy.communicate(timeout=30)
    finally:
        spy.kill()
    lines = [ln.split("\t") for ln in out.splitlines() if ln.startswith("ROBOT_STATE")]
    assert len(lines) >= 4, out
    assert all(cls == "marionette.lcmt_robot_state" for _, cls, _ in lines), out
    assert {int(u) for _, _, u in lines} <= {1000 * i for i in range(5)}, out


def test_lcm_spy_script_starts_and_finds_every_type(lcm_url):
    proc = subprocess.Popen(
        ["xvfb-run", "-a", str(ROOT / "scripts" / "lcm-spy"), f"--lcm-url={lcm_url}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # xvfb-run does not pass SIGTERM on: the whole group is stopped
    )
    try:
        line = wait_for_line(proc.stdout, "LCM types", timeout_s=60)
        time.sleep(1.0)
        assert proc.poll() is None, "lcm-spy exited early"
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=10)
    assert line is not None and line.strip() == f"Found {NUM_TYPES} LCM types"


@pytest.mark.slow
def test_lcm_spy_decodes_signed_messages(build_dir, lcm_url, tmp_path):
    """A signed message is the plain LCM message followed by its trailer (lcmtypes/README.md):
    lcm-spy's decoders stop at the message's end, so it shows signed channels as plain ones."""
    from marionette import channels, lcmt_command
    from marionette.lcm_bus import LcmBus

    jar = build_dir / "lcmtypes" / "marionette_lcmtypes.jar"
    classpath = f"{jar}:/usr/share/java/lcm.jar:{tmp_path}"
    subprocess.run(
        [
            "javac",
            "-nowarn",
            "-cp",
            classpath,
            "-d",
            str(tmp_path),
            str(ROOT / "tests/java/SpyDecode.java"),
        ],
        check=True,
        timeout=120,
    )
    spy = subprocess.Popen(
        ["java", "-Djava.net.preferIPv4Stack=true", "-cp", classpath, "SpyDecode", lcm_url, "6000"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert wait_for_line(spy.stdout, "READY", timeout_s=30) is not None
        with LcmBus(lcm_url, key=b"k" * 32) as bus:
            msg = lcmt_command()
            msg.command = "hold"
            for i in range(5):
                msg.utime = 1000 + i
                bus.publish(channels.COMMAND, msg)
                time.sleep(0.05)
        out, _ = spy.communicate(timeout=30)
    finally:
        spy.kill()
    lines = [ln.split("\t") for ln in out.splitlines() if ln.startswith("COMMAND")]
    assert len(lines) >= 4, out
    assert all(cls == "marionette.lcmt_command" for _, cls, _ in lines), out
    assert {int(u) for _, _, u in lines} <= {1000 + i for i in range(5)}, out
