"""Real-time pacer, held inputs and watchdog with a fake clock."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dcsms_ros.protocols.pacer import HeldInputs, Pacer, Publications, Watchdog


def test_deadlines_and_a_dropped_backlog() -> None:
    """At 1 kHz sample k is due at t0 + k ms; more than 20 behind drops the backlog."""
    p = Pacer(1000.0, max_burst=20)
    p.start(100.0)
    assert p.due(100.0, 0) == 1 and p.due(100.0, 1) == 0
    assert math.isclose(p.wait_s(100.0, 1), 0.001)
    assert p.due(100.0105, 1) == 10  # catching up in a burst: 9 of them after their deadline
    assert p.late == 9 and p.overruns == 0
    assert p.due(100.5, 11) == 1 and p.overruns == 489  # 500 due: 489 dropped, 1 computed
    assert p.late == 9
    assert math.isclose(p.wait_s(100.5, 12), 0.001, abs_tol=1e-9)


@pytest.mark.parametrize("k0", [0, 7])
def test_the_schedule_starts_when_the_loop_first_asks(k0: int) -> None:
    """Not started, the first due() makes sample k due then: a loop that first runs 3 ms after
    the handshake computes one sample, none late; started at the handshake it caught up
    with a burst of late ones."""
    p = Pacer(2000.0)
    assert not p.started
    assert p.due(10.003, k0) == 1 and p.started and p.late == 0
    assert math.isclose(p.wait_s(10.003, k0 + 1), 0.0005)
    assert p.due(10.0035, k0 + 1) == 1 and p.late == 0
    early = Pacer(2000.0)
    early.start(10.0)
    assert early.due(10.003, 0) == 7 and early.late == 6


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_late_counts_the_samples_computed_after_the_next_was_due(seed: int) -> None:
    """A plant that wakes with random delays: ``late`` is the number of samples it computed
    at a time when the following sample was already due, counted from the wake times."""
    rng = np.random.default_rng(seed)
    rate, t0 = 1000.0, 50.0
    p = Pacer(rate, max_burst=20)
    p.start(t0)
    k = late = 0
    now = t0
    for _ in range(2000):
        for _ in range(p.due(now, k)):
            late += now >= t0 + (k + 1) / rate  # the next sample was due already
            k += 1
        now = max(now, t0 + k / rate) + rng.exponential(0.4e-3)  # wakes up to ~3 ms late
    assert p.overruns == 0 and 0 < late < k
    assert p.late == late


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_woke_late_counts_the_deadlines_missed_after_the_loop_asked_to_wake(seed: int) -> None:
    """A loop that asks to wake at a time of its choice and gets the CPU later: of its late
    samples, ``woke_late`` counts those whose following sample fell due between the time it
    asked for and the time it ran (computed here sample by sample)."""
    rng = np.random.default_rng(seed)
    rate, t0 = 2000.0, 20.0
    p = Pacer(rate, max_burst=1000)
    p.start(t0)
    k = late = woke = 0
    asked = now = t0
    for _ in range(3000):
        for _ in range(p.due(now, k, now - asked)):
            nxt = t0 + (k + 1) / rate
            late += now >= nxt
            woke += asked < nxt <= now
            k += 1
        busy = now + rng.exponential(0.1e-3)  # the loop's own work may overrun a deadline
        asked = max(busy, t0 + k / rate - rng.uniform(0.0, 0.1e-3))
        now = asked + (rng.exponential(2e-3) if rng.random() < 0.05 else 20e-6)
    assert p.overruns == 0 and 0 < woke < late < k
    assert (p.late, p.woke_late) == (late, woke)


def test_a_loop_that_woke_in_time_has_no_late_wake_ups() -> None:
    """Woken in time, a loop that falls behind by its own work counts no late wake-up; a
    backlog dropped after a late wake-up counts there too."""
    p = Pacer(1000.0, max_burst=20)
    p.start(0.0)
    assert p.due(0.0105, 0) == 11 and p.late == 10 and p.woke_late == 0
    assert p.due(0.0155, 11, 0.0) == 5 and p.woke_late == 0
    # asked to wake at 18.1 ms, when its own work had missed 2 deadlines already
    assert p.due(0.0185, 16, woke_late_s=0.0004) == 3 and p.late == 16 and p.woke_late == 0
    # asked for 19.2 ms, ran at 50.5 ms: 31 deadlines passed meanwhile, dropped
    assert p.due(0.0505, 19, woke_late_s=0.0313) == 1
    assert p.overruns == 31 and p.woke_late == 31


@pytest.mark.parametrize(("now", "woke_late_s", "paused_s", "late", "woke", "paused"), [
    (0.0052, 0.0, 0.004, 4, 0, 4),  # a 4 ms pause while it worked: every late one is the pause's
    (0.0062, 0.0, 0.004, 5, 0, 4),  # and 1 ms of its own work more: one is its own
    (0.0100, 0.002, 0.003, 9, 2, 3),  # asleep 2 ms late, paused 3 ms before: 4 its own
    (0.0052, 0.0, 0.0002, 4, 0, 0),  # a pause shorter than the rest of a period moves none
    (0.0100, 0.0095, 0.004, 9, 9, 0),  # the late wake-up took them all: none left to pause
])
def test_a_pause_while_the_loop_worked_pushed_back_the_deadlines_after_it(
        now: float, woke_late_s: float, paused_s: float, late: int, woke: int,
        paused: int) -> None:
    """Of the deadlines missed at ``now``, :attr:`Pacer.woke_late` counts those that passed
    after the late wake-up began, :attr:`Pacer.paused` those in the pause before it (the
    deadlines the loop would have met without either), the rest are the loop's own."""
    p = Pacer(1000.0, max_burst=1000)
    p.start(0.0)
    assert p.due(0.0, 0) == 1
    assert p.due(now, 1, woke_late_s, paused_s) == late + 1
    assert (p.late, p.woke_late, p.paused) == (late, woke, paused)


def test_held_inputs_go_stale_and_count_it_once() -> None:
    """A force older than the timeout is zero; each fresh -> stale transition is one event."""
    h = HeldInputs(["a", "b"], timeout_s=0.01, zero=0.0)
    vals, newly = h.take(0.0)
    assert vals == {"a": 0.0, "b": 0.0} and newly == []  # never seen: stale from the start
    h.put("a", 3.0, 1.0)
    h.put("b", 4.0, 1.0)
    assert h.take(1.005) == ({"a": 3.0, "b": 4.0}, [])
    h.put("a", 5.0, 1.012)
    assert h.take(1.015) == ({"a": 5.0, "b": 0.0}, ["b"])
    assert h.take(1.016)[1] == [] and h.stale_events == {"a": 0, "b": 1}
    # stale samples count every take after the first arrival, not the start-up before it
    assert h.stale_samples == {"a": 0, "b": 2}
    assert h.arrived("a") == 1.012 and h.arrived("zz") == -math.inf


def test_a_held_value_counts_from_its_own_time_and_an_older_one_is_ignored() -> None:
    """The plant puts a force valid from its sample's publication: an answer to an old sample
    is stale at once, and it never replaces a newer answer that arrived first."""
    h = HeldInputs(["a"], timeout_s=0.01, zero=0.0)
    h.put("a", 1.0, 2.000)
    h.put("a", 9.0, 1.985)  # a reordered, older answer: ignored
    assert h.take(2.005) == ({"a": 1.0}, [])
    h.put("a", 2.0, 1.990)  # older than the held one: ignored, the held one stales
    assert h.take(2.011) == ({"a": 0.0}, ["a"])
    h.put("a", 3.0, 2.011)
    assert h.take(2.012) == ({"a": 3.0}, [])


def test_a_fresh_answer_to_an_older_sample_than_due_counts_as_delayed() -> None:
    """At 1 kHz, sample k published at k ms; at step k the plant is due the answer to k - 1.
    An answer to k - 2 (k - 1 skipped or late) is applied, fresh, and counted delayed; a stale
    one is stale, not delayed; none before the first answer; the due answer is on time."""
    h = HeldInputs(["a", "b"], timeout_s=0.01, zero=0.0)
    h.take(0.0005, due=-math.inf)  # step 0: nothing answerable yet
    assert h.delayed_samples == {"a": 0, "b": 0}
    h.put("a", 1.0, 0.000)
    h.put("b", 2.0, 0.000)
    assert h.take(0.0015, due=0.000)[0] == {"a": 1.0, "b": 2.0}  # step 1, both on time
    h.put("a", 3.0, 0.001)  # b skipped sample 1
    assert h.take(0.0025, due=0.001)[0] == {"a": 3.0, "b": 2.0}  # step 2: b applied 1 late
    assert h.delayed_samples == {"a": 0, "b": 1}
    assert h.take(0.0125, due=0.011)[0] == {"a": 0.0, "b": 0.0}  # both stale at step 12
    assert h.delayed_samples == {"a": 0, "b": 1} and h.stale_samples == {"a": 1, "b": 1}


def test_an_answer_counts_from_its_publication_on_schedule() -> None:
    """At 2 kHz on schedule (20 us of jitter) an answer counts from its sample's publication;
    one to a sample not yet published from its arrival, one forgotten never."""
    pubs = Publications(2000.0, size=256)
    assert pubs.answered(0, 7) == (None, 7)
    jitter = np.random.default_rng(3).uniform(0, 20_000, 300).astype(int)
    for k in range(300):
        pubs.put(k, 1_000_000_000 + k * 500_000 + int(jitter[k]))
    for k in (299, 250, 100):  # the newest, and older ones the newest's jitter does not move
        t_k = 1_000_000_000 + k * 500_000 + int(jitter[k])
        want = min(t_k, 1_000_000_000 + 299 * 500_000 + int(jitter[299]) - (299 - k) * 500_000)
        assert pubs.answered(k, 2**40) == (t_k, want) and abs(want - t_k) <= 20_000
        assert pubs.at_ns(k) == t_k
    assert pubs.answered(300, 5) == (None, 5)
    assert pubs.answered(43, 5) == (None, Publications.NEVER_NS) and pubs.at_ns(43) is None


@pytest.mark.parametrize("timeout_s, kept", [(0.01, 256), (0.5, 1021)])
def test_a_longer_timeout_keeps_every_answer_it_allows(timeout_s: float, kept: int) -> None:
    """Covering a 0.5 s timeout at 2 kHz (after 300 samples, keeping what was remembered): an
    answer 999 samples (0.4995 s) old still counts from its publication, where 256 samples
    forgot it; the default 10 ms timeout keeps 256."""
    pubs = Publications(2000.0)
    for k in range(300):
        pubs.put(k, 10**9 + k * 500_000)
    pubs.cover(timeout_s)
    assert pubs.size == kept
    assert [pubs.at_ns(k) for k in (299, 44)] == [10**9 + 299 * 500_000, 10**9 + 44 * 500_000]
    for k in range(300, 1300):
        pubs.put(k, 10**9 + k * 500_000)
    old = pubs.answered(1299 - 999, 2**40)
    assert (old[0] is not None) == (timeout_s > 0.1)


def _answers_applied_late(seed: int, by_publication: bool) -> tuple[int, int]:
    """A 2 kHz plant that wakes late (0.3 ms mean, 9 ms one time in 50) and is preempted for
    up to 9 ms before 5 % of its publications; after each wake-up the controller answers the
    newest sample less 40 (20 ms, twice the 10 ms timeout). Returns the samples that took
    that answer as fresh, and the samples taken, aging it from ``answered``'s time or, if
    ``by_publication``, from its sample's publication alone."""
    rng = np.random.default_rng(seed)
    rate, lag = 2000.0, 40
    pacer, pubs = Pacer(rate), Publications(rate)
    held = HeldInputs(["fb"], timeout_s=0.01, zero=0.0)
    t, k, fresh, taken = 0.0, 0, 0, 0
    while t < 2.0:
        due_t = pacer.t0 + k / rate if pacer.started else t
        t = max(t, due_t) + rng.exponential(0.3e-3) * (30 if rng.random() < 0.02 else 1)
        for _ in range(pacer.due(t, k)):
            if rng.random() < 0.05:
                t += rng.uniform(0.0, 0.009)
            pubs.put(k, int(t * 1e9))
            vals, _ = held.take(t)
            if k > 2 * lag:
                taken += 1
                fresh += vals["fb"] != 0.0
            k += 1
            t += 20e-6
        if k > lag:
            t_pub, valid = pubs.answered(k - 1 - lag, int(t * 1e9))
            assert t_pub is not None and valid <= t_pub
            held.put("fb", 1.0, (t_pub if by_publication else valid) * 1e-9)
    return fresh, taken


def test_an_old_answer_is_stale_however_the_plant_catches_up() -> None:
    """An answer 40 samples older than the newest is never applied, whatever the bursts and
    preemptions. Aged from its sample's publication alone it was, in samples published late in
    a burst (CI, stop 65: 0.4 % of a phase of such answers applied): this test fails on that."""
    runs = [_answers_applied_late(seed, by_publication=False) for seed in range(5)]
    old = [_answers_applied_late(seed, by_publication=True) for seed in range(5)]
    assert all(taken > 3000 for _, taken in runs)
    assert [fresh for fresh, _ in runs] == [0] * 5
    assert sum(fresh for fresh, _ in old) > 0


def test_watchdog() -> None:
    """Fresh, then stale once, stays stale (repeated zero force), back on the next input."""
    w = Watchdog(0.01)
    assert w.check(5.0) is None and w.wait_s(5.0) is None  # nothing arrived yet
    assert not w.feed(1.0)
    assert w.check(1.005) is None and math.isclose(w.wait_s(1.005), 0.005)
    assert w.check(1.02) is True and math.isclose(w.wait_s(1.02), 0.0025)
    assert w.check(1.03) is False and w.stale_events == 1
    assert math.isclose(w.wait_s(1.03), 0.0025)
    assert w.feed(1.04) and not w.stale


def test_a_stale_watchdog_repeats_every_quarter_timeout_however_often_asked() -> None:
    """A composed driver asks at every wake-up of any node (here every 0.1 ms for 1 s)."""
    w = Watchdog(0.01)
    w.feed(0.0)
    said = [(t, r) for t in np.arange(0.0, 1.0, 1e-4) if (r := w.check(float(t))) is not None]
    assert said[0][1] is True and all(r is False for _, r in said[1:])
    gaps = np.diff([t for t, _ in said])
    assert len(said) == pytest.approx((1.0 - 0.01) / 0.0025, abs=2)
    assert gaps.min() >= 0.0025 - 1e-9 and gaps.max() <= 0.0025 + 1e-4 + 1e-9


@pytest.mark.parametrize("timeout_s", [0.001, 0.01, 0.025])
def test_a_watchdog_that_waits_has_nothing_to_say(timeout_s: float) -> None:
    """A controller's hot loop skips :meth:`Watchdog.check` while :meth:`Watchdog.wait_s` is
    positive or None: at each of 0.1 ms steps over inputs that stop and resume, a check in
    such a moment returns None, and the checks it does make say what checking always says."""
    always, skipping = Watchdog(timeout_s), Watchdog(timeout_s)
    rng = np.random.default_rng(7)
    inputs = set(np.flatnonzero(rng.random(20_000) < 0.3).tolist()) - set(range(5_000, 9_000))
    said_always, said_skipping = [], []
    for k in range(20_000):
        t = k * 1e-4
        if k in inputs:
            always.feed(t)
            skipping.feed(t)
        said_always.append(always.check(t))
        left = skipping.wait_s(t)
        said_skipping.append(None if left is None or left > 0.0 else skipping.check(t))
    assert said_skipping == said_always
    assert said_always.count(True) >= 1 and said_always.count(False) >= 1
