"""Time-gap statistics of a recorded topic whose stamps do not advance."""

from __future__ import annotations

from dcsms_ros.analysis.gaps import WARMUP, TopicStats
from dcsms_ros.cdr import TWIST_STAMPED


def test_zero_stamps_keep_the_warm_up_bounded_and_a_later_period_settles() -> None:
    """A driver that leaves its stamps zero gives no period; the warm-up must not grow with
    every message (it was rescanned at each one: quadratic in the recording's length). Once
    the stamps advance at 1 ms the period settles and a 5 ms hole is a time gap."""
    st = TopicStats("/t", TWIST_STAMPED, stamped=True)
    seq = 0
    for _ in range(50 * WARMUP):
        seq += 1
        st.add(seq, 0, seq)
        assert len(st._warm) <= WARMUP  # the memory (and per-message work) bound at stake
    assert st.median_period_ns is None and st.ok
    t = 10**9
    for k in range(3 * WARMUP):
        seq += 1
        t += 5_000_000 if k == 2 * WARMUP else 1_000_000
        st.add(seq, t, seq)
    assert st.median_period_ns == 1_000_000
    # the jump from zero to the first real stamp is a gap too
    assert st.time_gaps == 2 and st.backwards == 0 and st.seq_gaps == 0


def test_a_backwards_stamp_among_stamps_that_do_not_advance_is_counted() -> None:
    """Stamps 5 s, ..., then 3 s, ...: no period ever, but the step back is still reported."""
    st = TopicStats("/t", TWIST_STAMPED, stamped=True)
    stamps = [5 * 10**9] * WARMUP + [3 * 10**9] * (2 * WARMUP)
    for i, s in enumerate(stamps, 1):
        st.add(i, s, i)
    st.finish()
    assert st.backwards == 1 and st.time_gaps == 0 and not st.ok
