"""marionette-logger: every message that reached it is in the log, however long it waited for the
CPU; bad options and unwritable files are one line, never a traceback."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import time
from pathlib import Path

import pytest

import lcm
from marionette.lcm_bus import logger_command, private_lcm_url, udp_receive_buffer_drops

LOGGER_EXIT_S = 10.0


def _kernel_buffer_bytes() -> int:
    with open("/proc/sys/net/core/rmem_default") as f:
        return int(f.read())


def _wait_subscribed(publisher: lcm.LCM, log: Path, timeout_s: float = 10.0) -> None:
    """Publishes PROBE until the logger has written one to ``log`` (those sent before it
    subscribed are not for it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        publisher.publish("PROBE", b"probe")
        time.sleep(0.05)
        if log.exists() and log.stat().st_size > 0:
            return
    pytest.fail(f"marionette-logger wrote nothing to {log} in {timeout_s} s")


def _events(log: Path) -> list[tuple[str, bytes]]:
    return [(e.channel, e.data) for e in lcm.EventLog(str(log), "r")]


def test_every_message_is_logged_in_order_after_the_logger_was_kept_off_the_cpu(tmp_path):
    # SIGSTOP keeps every thread of the logger off the CPU while a burst arrives: the burst waits
    # in the kernel's socket buffer, and on SIGCONT LCM's reader thread hands it over faster than
    # the handler writes it. lcm-logger drops, there, all but 30 waiting messages (LCM's default
    # subscription queue); none may be lost here. The burst is sized to fit the kernel's buffer
    # (skbs take about 1 KiB per small datagram), so a kernel drop is not what is tested.
    rng = random.Random(7)
    burst = max(200, min(3000, _kernel_buffer_bytes() // 4 // 1024))
    url = private_lcm_url()
    log = tmp_path / "run.lcmlog"
    publisher = lcm.LCM(url)
    logger = subprocess.Popen(
        logger_command(url, log, exclude="^CAMERA_"), stdout=subprocess.PIPE, text=True
    )
    try:
        _wait_subscribed(publisher, log)
        drops_before = udp_receive_buffer_drops()
        os.kill(logger.pid, signal.SIGSTOP)
        payloads = []
        for i in range(burst):
            payload = i.to_bytes(4, "little") + rng.randbytes(rng.randrange(8, 600))
            payloads.append(payload)
            publisher.publish("BURST", payload)
            if i % 10 == 0:
                publisher.publish("CAMERA_HEAD", b"frame")
        time.sleep(0.2)
        os.kill(logger.pid, signal.SIGCONT)
        time.sleep(0.5)
        drops = udp_receive_buffer_drops()
        logger.send_signal(signal.SIGINT)
        out, _ = logger.communicate(timeout=LOGGER_EXIT_S)
    finally:
        if logger.poll() is None:  # a failed assertion above: never leave it stopped
            os.kill(logger.pid, signal.SIGCONT)
            logger.kill()
    assert drops_before is None or drops == drops_before, "the kernel dropped datagrams"
    assert logger.returncode == 0
    events = _events(log)
    assert [d for c, d in events if c == "BURST"] == payloads
    assert not [c for c, _ in events if c.startswith("CAMERA_")]
    assert {c for c, _ in events} == {"PROBE", "BURST"}
    excluded = len(range(0, burst, 10))
    assert out.strip() == (
        f"marionette-logger: {len(events)} messages written to {log} "
        f"({excluded} on excluded channels)"
    )


@pytest.mark.parametrize(
    "args, code, message",
    [
        (["--bogus"], 2, "unknown option --bogus"),
        (["--lcm-url=udpm://239.255.76.67:7667?ttl=0"], 2, "-f FILE is required"),
        (["-f"], 2, "-f needs a value"),
        (["-f", "x.lcmlog", "--exclude=("], 2, "--exclude ( is not a regex"),
        (["-f", "/no-such-folder/run.lcmlog"], 1, "cannot write /no-such-folder/run.lcmlog"),
    ],
)
def test_bad_options_and_unwritable_logs_are_one_line(tmp_path, args, code, message):
    command = logger_command(private_lcm_url(), tmp_path / "unused.lcmlog")[:1] + args
    run = subprocess.run(command, capture_output=True, text=True, timeout=10, cwd=tmp_path)
    assert run.returncode == code
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("marionette-logger: ") and message in lines[0]
    assert "Traceback" not in run.stderr and run.stdout == ""


def test_help_prints_usage_and_records_nothing(tmp_path):
    command = logger_command(private_lcm_url(), tmp_path / "run.lcmlog") + ["--help"]
    run = subprocess.run(command, capture_output=True, text=True, timeout=10)
    assert run.returncode == 0 and run.stdout.startswith("usage: marionette-logger")
    assert not (tmp_path / "run.lcmlog").exists()
