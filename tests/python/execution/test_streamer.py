"""Streaming ahead of the controller's clock: contiguous chunks, bounded look-ahead and bursts,
one end-of-reference flag, early stop on a force event."""

from __future__ import annotations

import numpy as np
import pytest

from marionette.execution.streamer import ReferenceStreamer


def _references(n: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    t = np.arange(n, dtype=float)
    return {"posture": (np.c_[t, -t], np.ones((n, 2))), "com": (np.c_[t, t, t], np.zeros((n, 3)))}


def test_chunks_are_contiguous_bounded_ahead_and_end_once():
    sent = []
    n, dt = 2345, 1000
    s = ReferenceStreamer(
        sent.append,
        7,
        _references(n),
        start_utime=10_000,
        dt_us=dt,
        chunk_samples=200,
        lookahead_s=1.0,
        max_chunks_per_pump=4,
    )
    now = 0
    while not s.done:
        s.pump(now)
        for m in sent:  # never more than the look-ahead (plus one chunk) ahead of the clock
            assert m.utime < now + 1_000_000
        now += 10_000
    for task, (values, derivatives) in _references(n).items():
        chunks = [m for m in sent if m.task_name == task]
        starts = [m.utime for m in chunks]
        assert starts[0] == 10_000
        # Each chunk starts one period after the previous one's last sample.
        for a, b in zip(chunks, chunks[1:]):
            assert b.utime == a.utime + a.num_samples * dt
        np.testing.assert_array_equal(np.vstack([m.value for m in chunks]), values)
        np.testing.assert_array_equal(np.vstack([m.derivative for m in chunks]), derivatives)
        assert [m.last_chunk for m in chunks] == [False] * (len(chunks) - 1) + [True]
        assert all(m.controller_id == 7 for m in chunks)
        # Numbered from 0 per task: the controller refuses a chunk whose predecessor was lost.
        assert [m.sequence for m in chunks] == list(range(len(chunks)))
    assert s.end_utime == 10_000 + (n - 1) * dt


def test_bursts_are_limited_per_pump():
    sent = []
    s = ReferenceStreamer(
        sent.append,
        1,
        _references(5000),
        0,
        chunk_samples=100,
        lookahead_s=4.0,
        max_chunks_per_pump=3,
    )
    assert s.pump(0) == 3 and len(sent) == 3 * 2  # 3 chunks of each of the 2 tasks
    assert s.pump(0) == 3


def test_early_stop_ends_every_reference_at_the_current_sample():
    sent = []
    s = ReferenceStreamer(sent.append, 1, _references(3000), 0, chunk_samples=500, lookahead_s=2.0)
    s.pump(0)
    s.stop_early(now_utime=300_000, lead_us=20_000)
    last = [m for m in sent if m.last_chunk]
    assert {m.task_name for m in last} == {"posture", "com"}
    for m in last:
        assert m.num_samples == 1 and m.utime == 320_000
        assert m.sequence == 4, "the stop follows the 4 chunks sent (2 s of 500 samples)"
    assert s.done and s.end_utime == 320_000
    post = next(m for m in last if m.task_name == "posture")
    assert post.value[0] == [320.0, -320.0] and post.derivative[0] == [0.0, 0.0]


def test_an_early_stop_past_what_was_sent_holds_the_last_sample_sent():
    """A stop due after the samples sent (the streamer fell behind the clock) holds the last one
    sent: a lone sample beyond a gap would start the controller's stream afresh there."""
    sent = []
    s = ReferenceStreamer(sent.append, 1, _references(5000), 0, chunk_samples=500, lookahead_s=1.0)
    s.pump(0)  # samples 0 .. 999
    s.stop_early(now_utime=2_500_000)
    assert {m.utime for m in sent if m.last_chunk} == {999_000}
    assert s.end_utime == 999_000


@pytest.mark.parametrize(
    "kwargs, message",
    [({"lookahead_s": 6.0}, "lookahead_s"), ({"chunk_samples": 2000}, "chunk_samples")],
)
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ReferenceStreamer(lambda m: None, 1, _references(10), 0, **kwargs)
