"""Trip feed: per-stage streams (repeats, late stages, a reset) to aligned checkpoint rows that
trip on the same sample as the whole series pushed at once."""

from __future__ import annotations

import numpy as np

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
        feed.add(1, k * NS, v[k, 1])  # stage 2 first: rows wait for stage 1
        assert feed.complete_ns() == (k - 1) * NS if k else feed.complete_ns() == -1
        feed.add(0, k * NS, v[k, 0])
        feed.add(0, k * NS, v[k, 0] + 1.0)  # a repeat (retransmission) is ignored
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
        feed.add(0, k * NS, v[k, 0])
        if k % 97 == 0 and got is None:
            got = feed.judge()
    assert got is not None and got.stage == 1


def test_reset_resumes_at_a_checkpoint_block() -> None:
    """After a reset the rows before the next block start are dropped, so the checker's
    checkpoints keep the plant's sample indices."""
    feed = TripFeed(TripChecker(ControlConfig(), RATE, 1, 1), RATE)
    for k in range(150):
        feed.add(0, k * NS, np.zeros(1))
    feed.judge(lag_ns=0)
    assert feed.checker.k == 150
    feed.reset()
    for k in range(150, 260):
        feed.add(0, k * NS, np.zeros(1))
    feed.judge(lag_ns=0)
    assert feed.checker.k == 60 and feed.judged_ns == 259 * NS  # fed from sample 200 on
