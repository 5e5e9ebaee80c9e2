"""Signed commands across two hosts (README, "Signed commands on two machines"): the controller on
host A takes signed commands only; the user's session on host B, with the same key file, drives
and tunes it as without signing; an unsigned sender on host B cannot estop it, and is counted."""

from __future__ import annotations

import json
import os
import secrets
import subprocess
import sys
from pathlib import Path

import pytest

from deploy.netns import NetnsUnavailable, two_hosts

URL = "udpm://239.255.76.67:7793?ttl=1"
HERE = Path(__file__).parent

INTRUDER = """
import json, sys, time
from marionette import channels, lcmt_command
from marionette.control.client import ControllerClient
from marionette.lcm_bus import LcmBus
url = sys.argv[1]
with ControllerClient(url) as c, LcmBus(url, key=False) as intruder:
    c.wait_ready(30)
    msg = lcmt_command()
    msg.command, msg.source = "estop", "intruder"
    for _ in range(5):
        intruder.publish(channels.COMMAND, msg)
        time.sleep(0.05)
    c.wait(lambda c: c.status.num_rejected >= 5, 10)
    c.wait_time(0.3)
    print(json.dumps({"mode": c.status.mode,
                      "reasons": dict(zip(c.status.rejection_reason, c.status.rejection_count))}))
"""


@pytest.fixture
def hosts():
    try:
        with two_hosts() as pair:
            yield pair
    except NetnsUnavailable as e:
        pytest.skip(str(e))


@pytest.mark.slow
def test_signed_commands_across_two_hosts(hosts, build_dir, tmp_path):
    a, b = hosts
    key = tmp_path / "marionette.key"
    key.write_text(secrets.token_hex(32) + "\n")
    key.chmod(0o600)
    env = dict(os.environ, MARIONETTE_KEY=str(key))
    log = open(tmp_path / "controller.log", "w")
    controller = subprocess.Popen(
        a.command(
            [str(build_dir / "marionette-controller"), "--robot", "ur10", "--backend"]
            + ["kinematic", "--lcm-url", URL, "--camera-rate", "0", "--duration", "90"]
        ),
        stdout=log,
        stderr=subprocess.STDOUT,
        env=env,
    )
    try:
        session = subprocess.run(
            b.command([sys.executable, str(HERE / "remote_session.py"), URL]),
            capture_output=True,
            text=True,
            timeout=120,
            env=env,
        )
        assert session.returncode == 0, session.stderr[-3000:]
        result = json.loads(session.stdout.strip().splitlines()[-1])
        intruder = subprocess.run(
            b.command([sys.executable, "-c", INTRUDER, URL]),
            capture_output=True,
            text=True,
            timeout=120,
            env=env,
        )
        assert intruder.returncode == 0, intruder.stderr[-3000:]
        seen = json.loads(intruder.stdout.strip().splitlines()[-1])
    finally:
        controller.terminate()
        controller.wait(15)
        log.close()
    text = (tmp_path / "controller.log").read_text()
    assert controller.returncode == 0, text[-3000:]
    assert "commands: signed only" in text
    # Signed: the session drove and tuned the controller, nothing of it refused.
    assert result["moved"] > 0.09 and result["error"] < 0.01, result
    assert result["rejected"] == 0 and result["gain_after"] == 2.0, result
    # Unsigned: five estops refused, none obeyed.
    assert seen["reasons"].get("COMMAND: unsigned") == 5, seen
    assert seen["mode"] != "estopped", seen
