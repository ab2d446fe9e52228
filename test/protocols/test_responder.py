"""Answer protocol: a repeat gets the cached answer, an older stamp is dropped, the first
answer waits for the gate (fake stamps, readers and clock)."""

from __future__ import annotations

import pytest

from dcsms_ros.protocols.responder import (
    Answerer,
    StampResponder,
    Verdict,
    skip_free_ns,
    skipped,
)


def test_new_repeat_old() -> None:
    r: StampResponder[bytes] = StampResponder()
    assert r.judge(10) is Verdict.NEW
    assert r.store(10, b"ten") == b"ten"
    assert r.judge(10) is Verdict.REPEAT and r.cache == b"ten"
    assert r.judge(5) is Verdict.OLD
    assert r.judge(11) is Verdict.NEW  # not stored: judged again as new
    assert r.judge(11) is Verdict.NEW
    assert (r.repeats, r.out_of_order, r.last_ns) == (1, 1, 10)


def test_nothing_cached_yet_is_new() -> None:
    """Before any answer a stamp is new (even -1), never a repeat."""
    r: StampResponder[str] = StampResponder()
    assert r.judge(-1) is Verdict.NEW and r.repeats == 0


class _Fake:
    """A fake reader view and clock for :class:`Answerer`."""

    def __init__(self, gated: bool, timeout_s: float = 5.0) -> None:
        self.sent: list[str] = []
        self.matched = False
        self.now = 0.0
        self.timeouts = 0
        self.a: Answerer[str] = Answerer(self.sent.append, gated, lambda: self.matched,
                                         timeout_s, self._timeout, lambda: self.now)

    def _timeout(self) -> None:
        self.timeouts += 1

    def feed(self, stamp_ns: int) -> bool:
        """One input: compute ``"a<stamp>"`` when due; True if computed."""
        if not self.a.due(stamp_ns):
            return False
        self.a.reply(stamp_ns, f"a{stamp_ns}")
        return True


def test_answer_once_repeat_from_cache_drop_old() -> None:
    f = _Fake(gated=False)
    stamps = [0, 500, 500, 1000, 500, 1000, 1500]
    computed = [f.feed(s) for s in stamps]
    assert computed == [True, True, False, True, False, False, True]
    assert f.sent == ["a0", "a500", "a500", "a1000", "a1000", "a1500"]
    assert (f.a.repeats, f.a.out_of_order, f.a.last_ns) == (2, 1, 1500)


def test_gated_first_sample_waits_for_readers_then_never_again() -> None:
    """Held samples are neither computed nor published nor remembered: the retransmission
    of the same stamp is computed once the readers match."""
    f = _Fake(gated=True)
    assert not f.feed(0) and not f.feed(0)
    f.now = 1.0
    f.matched = True
    assert f.feed(0) and f.sent == ["a0"]
    f.matched = False  # a reader going away later does not close the gate
    assert f.feed(500) and f.sent == ["a0", "a500"]
    assert f.timeouts == 0 and f.a.repeats == 0


@pytest.mark.parametrize("timeout_s", [0.5, 5.0])
def test_gate_opens_after_timeout_and_reports_once(timeout_s: float) -> None:
    f = _Fake(gated=True, timeout_s=timeout_s)
    f.now = 10.0
    assert not f.feed(0)
    f.now = 10.0 + timeout_s  # not yet: strictly after the timeout
    assert not f.feed(0)
    f.now = 10.0 + timeout_s + 1e-3
    assert f.feed(0) and f.feed(500)
    assert f.timeouts == 1 and f.a.gate.timed_out and f.sent == ["a0", "a500"]


def test_list_answer_is_repeated_as_one_object() -> None:
    """A list answer (the decoupling's one message per body) is repeated as one object."""
    sent: list[list[bytes]] = []
    a: Answerer[list[bytes]] = Answerer(sent.append, False, lambda: True)
    assert a.due(7)
    a.reply(7, [b"x", b"y"])
    assert not a.due(7)
    assert sent == [[b"x", b"y"], [b"x", b"y"]] and sent[0] is sent[1]


@pytest.mark.parametrize(("last", "ns", "cap", "want"), [
    (-1, 5_000_000, 20, 0),  # nothing answered yet
    (0, 500_000, 20, 0),  # the next sample at 2 kHz
    (0, 1_500_000, 20, 2),  # two missing
    (0, 1_499_000, 20, 2),  # a stamp off by 1 us still counts whole samples
    (0, 50_000_000, 20, 20),  # a stall: at most cap
    (0, 0, 20, 0),
])
def test_skipped_counts_whole_missing_samples(last, ns, cap, want):
    assert skipped(last, ns, 2000.0, cap) == want


@pytest.mark.parametrize("rate", [2000.0, 3000.0, 1000.0, 1234.5])
def test_skipped_is_zero_below_the_skip_free_gap_and_one_from_one_and_a_half_periods(rate):
    """A caller may leave skipped() out for a gap below skip_free_ns: it is 0 there (the
    stamps of a rate whose period is no whole number of ns too), and 1 once a sample is
    missing."""
    free = skip_free_ns(rate)
    period = 1e9 / rate
    last = round(7 * period)
    for ns in range(last + 1, int(last + free) + 1, max(int(period / 50), 1)):
        assert skipped(last, ns, rate, 100) == 0, (rate, ns - last)
    assert skipped(last, round(9 * period), rate, 100) == 1
    assert free > period  # the usual gap, one period, is below it


def test_advance_marks_a_stamp_computed_without_an_answer_yet():
    """Real time: a sample computed as part of a burst is not recomputed if seen again, nor
    answered from a cache (it has none); an older stamp is old."""
    r: StampResponder[str] = StampResponder()
    r.advance(10)
    assert r.cache is None and r.last_ns == 10
    assert r.judge(5) is Verdict.OLD
    assert r.judge(11) is Verdict.NEW
    assert r.store(10, "a") == "a" and r.judge(10) is Verdict.REPEAT
