"""marionette-controller under 10^5 structure-aware mutations (marionette.lcm_fuzz, derived from
the .lcm schemas) on its six input channels: every message is refused and counted under its
channel with the reason the Python validator predicts independently of the C++ one (same schema,
another walker); the process stays alive, its memory flat, the robot still.

MARIONETTE_FUZZ_CONTROLLER names another binary to fuzz (`make sanitize`: the ASan + UBSan
build)."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

from marionette.control.fuzz import INPUTS, fuzz_controller
from tests_support import controller_running

UR10 = ["--robot", "ur10", "--backend", "kinematic", "--camera-rate", "0", "--status-rate", "200"]
MESSAGES = int(os.environ.get("MARIONETTE_FUZZ_MESSAGES", "100000"))


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


@pytest.mark.slow
def test_every_mutation_is_refused_counted_with_its_reason_and_nothing_moves(
    build_dir, lcm_url, tmp_path
):
    binary = os.environ.get("MARIONETTE_FUZZ_CONTROLLER")
    with controller_running(
        build_dir,
        lcm_url,
        tmp_path / "logs",
        *UR10,
        binary=Path(binary) if binary else None,
        ready_timeout=120.0,
    ) as c:
        c.wait_time(0.2)
        q0 = list(c.state.joint_position)
        rss0 = _rss_mb(c.process.popen.pid)
        report = fuzz_controller(c, MESSAGES, random.Random(20261126))
        rss1 = _rss_mb(c.process.popen.pid)
        print(
            f"\n{sum(report.sent.values())} messages in {report.seconds:.1f} s, "
            f"{report.skipped} mutations still valid (not sent); RSS {rss0:.0f} -> {rss1:.0f} MB"
        )
        for channel, (sent, counted) in report.per_channel().items():
            print(f"  {channel:16s} sent {sent:6d}  refused {counted:6d}")
        for kind, n in sorted(report.kinds.items()):
            print(f"  {kind:12s} {n:6d}")

        assert c.process.alive()
        # Counted once each, under its channel and the predicted reason.
        assert report.counted == report.expected, set(report.counted.items()) ^ set(
            report.expected.items()
        )
        assert sum(report.sent.values()) >= 0.99 * MESSAGES
        assert report.skipped <= 0.01 * MESSAGES
        for channel in INPUTS:  # every channel, every kind of lie
            assert report.sent[channel] >= MESSAGES // 7, channel
        assert len(report.kinds) == 9, report.kinds
        reasons = {reason for _, reason in report.expected}
        assert reasons >= {
            "wrong type",
            "past the end",
            "negative length",
            "over maximum",
            "unterminated string",
            "not a boolean",
            "out of range",
            "time out of range",
            "trailing bytes",
        }, reasons
        # Nothing moved, nothing was swapped in; memory stayed flat (no lying count allocated).
        assert c.status.num_switches == 0 and c.status.mode == "holding"
        assert list(c.state.joint_position) == q0
        assert rss1 - rss0 < 30.0, (rss0, rss1)
