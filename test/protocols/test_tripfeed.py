"""Trip feed: per-stage streams (repeats, late stages, a reset) to aligned checkpoint rows that
trip on the same sample as the whole series pushed at once."""

from __future__ import annotations

import numpy as np
import pytest

from dcsms_ros.core.config import ControlConfig
from dcsms_ros.core.trip import TripChecker
from dcsms_ros.protocols.tripfeed import TripFeed

RATE = 2000.0
NS = 500_000  # ns per sample


def _series() -> np.ndarray:
    rng = np.random.default_rng(3)
    v = rng.normal(0.0, 1e-4, (3000, 2, 1))
    t = np.arange(1000)
    v[2000:, 0, 0] += 5e-3 * np.sin(2 * np.pi * 20 * t / RATE) * t / 1000
    return v


def test_stream_feed_trips_where_the_whole_series_does() -> None:
    v = _series()
    ref = TripChecker(ControlConfig(), RATE, 2, 1)
    used, want = ref.push(v)
    assert want is not None and used == want.sample + 1
    feed = TripFeed(TripChecker(ControlConfig(), RATE, 2, 1), RATE)
    got = None
    for k in range(v.shape[0]):
        feed.add_block(1, [k * NS], v[k, 1])  # stage 2 first: rows wait for stage 1
        assert feed.complete_ns() == (k - 1) * NS if k else feed.complete_ns() == -1
        feed.add_block(0, [k * NS], v[k, 0])
        feed.add_block(0, [k * NS], v[k, 0] + 1.0)  # a repeat (retransmission) is ignored
        if (k + 1) % 100 == 0:
            got = feed.judge(k * NS)
            if got is not None:
                break
    assert got == want and feed.trip_ns == want.sample * NS and feed.gaps == 0


def test_real_time_judges_a_stage_whose_stream_is_silent_as_zero() -> None:
    """Real time: a stage that publishes nothing does not hold the other's rows back."""
    v = _series()
    feed = TripFeed(TripChecker(ControlConfig(), RATE, 2, 1), RATE)
    got = None
    for k in range(v.shape[0]):
        feed.add_block(0, [k * NS], v[k, 0])
        if k % 97 == 0 and got is None:
            got = feed.judge()
    assert got is not None and got.stage == 1


def test_reset_resumes_at_a_checkpoint_block() -> None:
    """After a reset the rows before the next block start are dropped, so the checker's
    checkpoints keep the plant's sample indices."""
    feed = TripFeed(TripChecker(ControlConfig(), RATE, 1, 1), RATE)
    for k in range(150):
        feed.add_block(0, [k * NS], np.zeros(1))
    feed.judge(lag_ns=0)
    assert feed.checker.k == 150
    feed.reset()
    for k in range(150, 260):
        feed.add_block(0, [k * NS], np.zeros(1))
    feed.judge(lag_ns=0)
    assert feed.checker.k == 60 and feed.judged_ns == 259 * NS  # fed from sample 200 on


@pytest.mark.parametrize("both", [False, True])
@pytest.mark.parametrize("lockstep", [True, False])
def test_blocks_with_repeats_and_a_lost_sample_give_the_rows_of_every_sample(
        lockstep: bool, both: bool) -> None:
    """Drained queues (blocks that repeat samples) and messages one by one give the checker
    every sample's rows; a sample lost on one stage is a gap in lockstep (the row is left
    out) and a zero in real time. Lost on both stages (the streams keep the same stamps,
    which lockstep takes as they are) it is a gap either way."""
    v = _series()[:400]
    lost = 123  # stage 2 (and with ``both`` stage 1) never gets this sample
    stamps = np.arange(v.shape[0]) * NS
    feeds = [TripFeed(TripChecker(ControlConfig(), RATE, 2, 1), RATE) for _ in range(2)]
    one, blk = feeds
    for k in range(v.shape[0]):
        if k != lost or not both:
            one.add_block(0, [int(stamps[k])], v[k, 0])
        if k != lost:
            one.add_block(1, [int(stamps[k])], v[k, 1])
    for j in range(0, v.shape[0], 64):
        sl = slice(max(j - 3, 0), j + 64)  # each block repeats the last 3 of the one before
        keep = [k for k in range(sl.start, min(sl.stop, v.shape[0])) if k != lost]
        blk.add_block(0, stamps[keep if both else sl], v[keep if both else sl, 0])
        blk.add_block(1, stamps[keep], v[keep, 1])
    want = v.copy()
    if lockstep or both:
        want = np.delete(want, lost, axis=0)
        want_stamps = np.delete(stamps, lost)
    else:
        want[lost, 1] = 0.0
        want_stamps = stamps
    through = int(stamps[-1]) if lockstep else None
    for feed in feeds:
        got, rows = feed.take(through, lag_ns=0)
        np.testing.assert_array_equal(got, want_stamps)
        np.testing.assert_array_equal(rows, want)
        assert feed.gaps == (1 if lockstep or both else 0) and feed.judged_ns == stamps[-1]
