"""The input-age guard: excess delay over the fastest recent delivery, whatever the epoch."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dcsms_ros.protocols.inputage import WINDOW_S, InputAge
from dcsms_ros.protocols.pacer import Pacer

RATE = 2000.0
PERIOD_NS = int(1e9 / RATE)
#: An arbitrary epoch between the plant's sample clock and the controller's monotonic clock.
EPOCH_NS = 123_456_789_012_345


def stream(delays_s: np.ndarray, drift: float = 0.0) -> tuple[list[int], list[int]]:
    """Stamps k / RATE and their arrivals on another clock (epoch, rate error ``drift``)."""
    k = np.arange(delays_s.size)
    stamps = k * PERIOD_NS
    arrivals = EPOCH_NS + np.round(stamps * (1.0 + drift) + delays_s * 1e9).astype(np.int64)
    return stamps.tolist(), arrivals.tolist()


def test_excess_is_the_delay_above_the_fastest_whatever_the_epoch():
    rng = np.random.default_rng(1)
    delays = 0.3e-3 + rng.exponential(0.4e-3, 40_000)  # 20 s of a loaded but healthy path
    age = InputAge(0.010)
    stamps, arrivals = stream(delays)
    excess = np.array([age.excess_s(s, a) for s, a in zip(stamps, arrivals, strict=True)])
    # the first two half windows: the floor is the fastest delivery since the start (the
    # blocks end on arrivals, so a few samples are left out at their edges)
    half = int(WINDOW_S / 2 * RATE)
    tail = slice(10, 2 * half - 10)
    floor = np.minimum.accumulate(delays)
    assert_allclose(excess[tail], delays[tail] - floor[tail], atol=2e-9)
    assert np.all(excess >= 0.0)
    assert age.old == 0 and age.last_old_ns == -1
    # the floor, within the first half window: the epoch on the arrival clock plus the
    # fastest delivery so far
    first = InputAge(0.010)
    assert first.floor_ns is None
    n = int(WINDOW_S / 2 * RATE) - 10
    for s, a in zip(stamps[:n], arrivals[:n], strict=True):
        first.fresh(s, a)
    assert first.floor_ns == EPOCH_NS + round(delays[:n].min() * 1e9)


def test_a_stall_makes_the_held_back_samples_old():
    delays = np.full(10_000, 0.5e-3)
    # the path stalls 60 ms at sample 6000: what was held back arrives in a burst
    stall = np.arange(6000, 6120)
    delays[stall] += (6120 - stall) / RATE
    age = InputAge(0.010)
    verdicts = [age.fresh(s, a) for s, a in zip(*stream(delays), strict=True)]
    old = np.flatnonzero(~np.array(verdicts))
    # excess > 10 ms: the samples more than 20 periods before the burst's end
    expected = stall[(6120 - stall) / RATE > 0.010]
    np.testing.assert_array_equal(old, expected)
    assert age.old == expected.size
    assert age.last_old_ns == int(expected[-1]) * PERIOD_NS
    assert age.worst_s == pytest.approx(0.060, abs=1e-8)


@pytest.mark.parametrize(("drift", "old"), [(1e-4, False), (-1e-4, False), (3e-3, True)])
def test_clock_drift_within_limit_over_window_is_followed(drift, old):
    """The floor's window follows a drift of up to limit / window (1e-3 here); a crystal
    drifts ~1e-5. A faster drift than that is read as a growing delay."""
    age = InputAge(0.010)
    n = int(60 * RATE)
    for s, a in zip(*stream(np.full(n, 0.5e-3), drift), strict=True):
        age.fresh(s, a)
    assert (age.old > 0) is old
    if not old:
        assert age.worst_s <= abs(drift) * WINDOW_S + 1e-9


def test_a_lasting_lag_becomes_the_floor_after_the_window():
    """Documented limit: the guard catches stalls and bursts, not a path slow for good."""
    delays = np.concatenate([np.full(int(5 * RATE), 0.5e-3), np.full(int(30 * RATE), 0.050)])
    age = InputAge(0.010)
    verdicts = np.array([age.fresh(s, a) for s, a in zip(*stream(delays), strict=True)])
    lag = verdicts[int(5 * RATE):]
    assert not lag[: int(5 * RATE)].any()  # the first half window of the lag: all old
    assert lag[int(WINDOW_S * RATE):].all()  # a whole window later it is the floor


def test_the_floor_outlives_a_silence():
    """A pause moves neither clock: samples held back by it are still judged old after it."""
    age = InputAge(0.010)
    stamps, arrivals = stream(np.full(4000, 0.5e-3))
    for s, a in zip(stamps, arrivals, strict=True):
        assert age.fresh(s, a)
    # 60 s of silence, then a sample taken at once and one delivered 40 ms late
    s = stamps[-1] + int(60e9)
    a = arrivals[-1] + int(60e9)
    assert age.fresh(s, a)
    assert not age.fresh(s + PERIOD_NS, a + PERIOD_NS + 40_000_000)


@pytest.mark.parametrize(("limit", "window"), [(0.0, 10.0), (0.01, 0.0), (-1.0, 1.0)])
def test_bad_limits_are_refused(limit, window):
    with pytest.raises(ValueError, match="must be > 0"):
        InputAge(limit, window)



def test_an_elastic_schedule_looks_late():
    """Why the guard stays off against the simulated plant: its pacer catches up to 20
    samples at once after a late wake-up and moves its schedule on beyond that, so samples
    published at once, and delivered at once, carry stamps that look up to a burst, or a
    whole move, late. The plant ages a force from its sample's publication: to it none of
    these is late."""
    pacer = Pacer(RATE)
    age = InputAge(0.010)
    path_s = 0.5e-3  # every sample delivered this long after its publication
    wake = np.arange(0.0, 4.0, 1.0 / RATE)
    wake[4000:] += 0.009  # one wake-up 9 ms late: a catch-up burst of 18 samples
    wake[6000:] += 0.030  # one 30 ms late: more than a burst, the schedule moves on
    k = 0
    old_at: list[bool] = []  # per sample: judged old
    moved_at: list[bool] = []  # per sample: computed at or after the late wake-up of 30 ms
    for i, now in enumerate(wake):
        for _ in range(pacer.due(float(now), k)):
            stamp = round(k * 1e9 / RATE)
            old_at.append(not age.fresh(stamp, EPOCH_NS + round((now + path_s) * 1e9)))
            moved_at.append(i >= 6000)
            k += 1
    assert pacer.late >= 17 and pacer.overruns > 20
    # every sample came path_s after its publication, yet from the move on the guard judges
    # each old (until its window forgets the floor from before: longer than this run), and
    # none of the catch-up burst (9 ms + path: under the limit)
    assert old_at == moved_at
