"""Signed command messages in Python (marionette.lcm_signing; the C++ twin is tested in
tests/cpp/lcm, the two against each other in tests/python/controller/test_controller_boundary.py)
and the Python processes' boundary (LcmBus): refused messages counted per channel and reason,
handlers never reached by garbage nor able to kill the handling thread, the heartbeat of a bus
that sent a controller spec."""

from __future__ import annotations

import time

import pytest

import marionette
from marionette import channels, lcmt_command, lcmt_controller_spec, lcmt_robot_state
from marionette.lcm_bus import LcmBus, MessageLog
from marionette.lcm_signing import (
    SIGNED_CHANNELS,
    TRAILER_SIZE,
    KeyFileError,
    Signer,
    Verifier,
    load_key,
)

KEY = b"k" * 32
NOW = 1_700_000_000_000_000


def test_signed_messages_pass_once_on_their_channel_only():
    signer, verifier = Signer(KEY), Verifier(KEY)
    message = lcmt_command().encode()
    signed = signer.sign(channels.COMMAND, message, NOW)
    assert len(signed) == len(message) + TRAILER_SIZE and signed.startswith(message)
    assert lcmt_command.decode(signed) is not None  # LCM's decoders (lcm-spy) stop at the end
    assert verifier.verify(channels.COMMAND, signed, NOW)[0] == message
    assert verifier.verify(channels.COMMAND, signed, NOW)[1] == "replayed"
    assert verifier.verify(channels.SIM_COMMAND, signed, NOW)[1] == "bad signature"
    assert verifier.verify(channels.COMMAND, message, NOW)[1] == "unsigned"
    assert Verifier(b"x" * 32).verify(channels.COMMAND, signed, NOW)[1] == "bad signature"
    for i in range(len(signed)):
        altered = bytearray(signed)
        altered[i] ^= 0x01
        reason = Verifier(KEY).verify(channels.COMMAND, bytes(altered), NOW)[1]
        assert reason in ("bad signature", "unsigned"), i
    old = signer.sign(channels.DG_REQUEST, message, NOW)
    assert Verifier(KEY).verify(channels.DG_REQUEST, old, NOW + 11_000_000)[1] == "stale signature"
    # Sequences increase even when the clock does not.
    burst = [signer.sign(channels.TASK_REFERENCE, message, NOW) for _ in range(50)]
    v = Verifier(KEY)
    assert all(v.verify(channels.TASK_REFERENCE, m, NOW)[0] == message for m in burst)


def test_key_files_must_be_long_and_private(tmp_path):
    good = tmp_path / "key"
    good.write_text("a" * 64 + "\n")
    good.chmod(0o600)
    assert load_key(good) == b"a" * 64
    for text, mode, words in (
        ("short\n", 0o600, "at least 32"),
        ("a" * 64, 0o644, "chmod 600"),
    ):
        path = tmp_path / f"bad{mode}"
        path.write_text(text)
        path.chmod(mode)
        with pytest.raises(KeyFileError, match=words):
            load_key(path)
    with pytest.raises(KeyFileError, match="not found"):
        load_key(tmp_path / "missing")


def test_the_signed_channels_are_the_controllers_inputs():
    text = (marionette.REPO_ROOT / "lcmtypes" / "CHANNELS.md").read_text().splitlines()
    marked = {ln.split("`")[1] for ln in text if ln.startswith("| `") and ln.endswith("| yes |")}
    assert marked == SIGNED_CHANNELS
    assert len(SIGNED_CHANNELS) == 6


def _state(tick: int) -> lcmt_robot_state:
    s = lcmt_robot_state()
    s.tick, s.robot_name = tick, "test"
    return s


def test_a_bus_refuses_garbage_and_survives_its_handlers(lcm_url, capsys):
    with LcmBus(lcm_url, key=False) as sender, LcmBus(lcm_url, key=False) as bus:
        got = []

        def handler(msg):
            got.append(msg.tick)
            if msg.tick == 2:
                raise RuntimeError("a bug in a handler")

        bus.subscribe(channels.ROBOT_STATE, lcmt_robot_state, handler)
        bus.start()
        garbage = bytearray(_state(0).encode())
        garbage[8 + 8 + 8 + 3] = 0x7F  # robot_name's length prefix: 2^31 - ...
        sender.lcm.publish(channels.ROBOT_STATE, bytes(garbage))
        sender.lcm.publish(channels.ROBOT_STATE, _state(1).encode()[:-3])
        for tick in (2, 3):
            sender.publish(channels.ROBOT_STATE, _state(tick))
        deadline = time.monotonic() + 5.0
        while len(got) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert got == [2, 3]  # garbage never reached it; its exception did not stop the thread
        assert bus.refusals == {
            (channels.ROBOT_STATE, "past the end"): 2,
            (channels.ROBOT_STATE, "handler error"): 1,
        }
    err = capsys.readouterr().err
    assert "lcm: refused a ROBOT_STATE message (past the end: robot_name" in err


def test_signed_and_unsigned_buses(lcm_url):
    with (
        LcmBus(lcm_url, key=KEY) as signed,
        LcmBus(lcm_url, key=False) as plain,
        LcmBus(lcm_url, key=KEY) as receiver,
        LcmBus(lcm_url, key=False) as keyless,
    ):
        logs = [MessageLog(b, channels.COMMAND, lcmt_command) for b in (receiver, keyless)]
        receiver.start()
        keyless.start()
        for bus, text in ((signed, "signed"), (plain, "plain")):
            msg = lcmt_command()
            msg.command = text
            bus.publish(channels.COMMAND, msg)
        assert logs[0].wait_for(lambda m: len(m) >= 1, 5.0)
        assert logs[1].wait_for(lambda m: len(m) >= 1, 5.0)
        time.sleep(0.2)
        assert [m.command for m in logs[0].messages] == ["signed"]
        assert receiver.refusals == {(channels.COMMAND, "unsigned"): 1}
        assert [m.command for m in logs[1].messages] == ["plain"]
        assert keyless.refusals == {(channels.COMMAND, "signed, no key"): 1}


def test_a_bus_that_sent_a_spec_beats_until_it_stops(lcm_url):
    with LcmBus(lcm_url, key=False) as listener:
        beats = MessageLog(listener, channels.COMMAND, lcmt_command)
        listener.start()
        driver = LcmBus(lcm_url, key=False)
        driver.publish(channels.ROBOT_STATE, _state(0))  # not a driver yet
        time.sleep(0.2)
        assert beats.messages == []
        driver.publish(channels.CONTROLLER_SPEC, lcmt_controller_spec())
        assert beats.wait_for(lambda m: len(m) >= 20, 5.0)
        assert {m.command for m in beats.messages} == {"heartbeat"}
        assert beats.messages[0].source == driver.source
        driver.stop()
        time.sleep(0.1)
        n = len(beats.messages)
        time.sleep(0.3)
        assert len(beats.messages) == n
