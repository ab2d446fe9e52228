"""Lockstep barrier with a fake clock: completion, retransmission, timeouts, absent, hold."""

from __future__ import annotations

from dcsms_ros.protocols.barrier import Action, LockstepBarrier

IDS = ["fb_stage1", "fb_stage2", "ff_stage1"]


def _barrier(**kw: object) -> LockstepBarrier:
    args = {"timeout_s": 0.5, "retry_s": 0.2, "absent_after": 3, "first_timeout_s": 10.0}
    args.update(kw)
    return LockstepBarrier([*IDS, "trip"], every={"trip": 100}, **args)  # type: ignore[arg-type]


def test_sample_completes_when_every_due_participant_answered() -> None:
    """Sample 5 waits for the three controllers (not the trip: no checkpoint), in any order;
    a repeated or mis-stamped answer does not count."""
    b = _barrier()
    assert b.begin(5, 2_500_000, now=0.0)
    assert b.due == IDS
    assert not b.offer("fb_stage2", 2_500_000, "w2")
    assert not b.offer("fb_stage2", 2_500_000, "again")  # the first answer counts
    assert not b.offer("ff_stage1", 2_000_000, "old")  # another sample's stamp
    assert not b.offer("fb_stage1", 2_500_000, "w1")
    assert b.missing() == ["ff_stage1"]
    assert b.offer("ff_stage1", 2_500_000, "w3")
    assert not b.waiting and b.got == {"fb_stage2": "w2", "fb_stage1": "w1", "ff_stage1": "w3"}


def test_checkpoint_sample_also_waits_for_the_trip_verdict() -> None:
    """After sample 99 ((k + 1) % 100 == 0) the trip participant is due too."""
    b = _barrier()
    assert b.due_at(98) == IDS and b.due_at(99) == [*IDS, "trip"]
    b.begin(99, 49_500_000, now=0.0)
    for c in IDS:
        b.offer(c, 49_500_000, c)
    assert b.waiting and b.missing() == ["trip"]
    assert b.offer("trip", 49_500_000)


def test_retransmit_then_timeout_then_absent_and_back() -> None:
    """A silent controller: republish after retry_s, fault after timeout_s, absent after three
    faults in a row (then not waited for), waited for again once it answers."""
    b = _barrier()
    for k in range(1, 4):
        t0 = 10.0 * k
        assert b.begin(k, k, now=t0)
        b.offer("fb_stage1", k)
        b.offer("fb_stage2", k)
        assert b.poll(t0 + 0.1) is Action.NONE
        assert b.poll(t0 + 0.25) is Action.RETRANSMIT
        assert b.poll(t0 + 0.3) is Action.NONE  # the next retry is retry_s later
        assert b.poll(t0 + 0.51) is Action.TIMEOUT
        missing, absent = b.expire()
        assert missing == ["ff_stage1"] and not b.waiting
        assert absent == (["ff_stage1"] if k == 3 else [])
    assert b.faults["ff_stage1"] == 3 and b.retransmits == 3 and b.state("ff_stage1") == "absent"
    assert b.begin(4, 4, now=50.0)
    b.offer("fb_stage1", 4)
    assert b.offer("fb_stage2", 4)  # the absent one is not waited for
    b.offer("ff_stage1", 3)  # any answer, even a late one, brings it back
    assert b.state("ff_stage1") == "ok" and b.begin(5, 5, now=60.0)
    assert b.due == IDS and b.missing() == IDS


def test_sample_zero_has_the_handshake_timeout_and_all_absent_does_not_wait() -> None:
    """Sample 0 waits first_timeout_s; with every due participant absent nothing waits."""
    b = _barrier(absent_after=1)
    b.begin(0, 0, now=0.0)
    assert b.poll(5.0) is Action.RETRANSMIT and b.poll(10.1) is Action.TIMEOUT
    assert b.next_deadline(10.1) > 0
    b.expire()
    assert not b.begin(1, 1, now=11.0)  # everyone absent after one miss: complete at once


def test_hold_stops_before_the_chosen_sample() -> None:
    """hold = 600: samples before it may go out, 600 may not until the hold moves."""
    b = _barrier()
    b.hold = 600
    assert b.may_publish(599) and not b.may_publish(600)
    b.hold = None
    assert b.may_publish(600)


def _last_barrier() -> LockstepBarrier:
    return LockstepBarrier([*IDS, "trip"], timeout_s=0.5, retry_s=0.2, absent_after=3,
                           first_timeout_s=10.0, every={"trip": 100}, last=["trip"])


def test_last_participant_is_asked_once_after_every_other_answered() -> None:
    """The trip verdict is asked only when the controllers' answers to the checkpoint sample
    are in (a trip's disable must not overtake them), once per sample."""
    b = _last_barrier()
    b.begin(99, 49_500_000, now=0.0)
    assert b.to_ask() == []
    for c in IDS[:-1]:
        b.offer(c, 49_500_000, c)
        assert b.to_ask() == []
    assert not b.offer(IDS[-1], 49_500_000, "w")
    assert b.to_ask() == ["trip"]
    assert b.to_ask() == []  # once
    assert b.asked == {"trip"}
    assert b.offer("trip", 49_500_000)
    b.begin(100, 50_000_000, now=1.0)  # no checkpoint: nothing to ask, a new sample forgets
    assert b.asked == set()
    for c in IDS:
        b.offer(c, 50_000_000, c)
    assert b.to_ask() == []


def test_a_controller_timeout_asks_the_last_participant_with_its_own_timeout() -> None:
    """A controller that misses a checkpoint sample is counted at the timeout; the sample then
    stays open for the trip verdict, asked now, with a fresh timeout."""
    b = _last_barrier()
    b.begin(99, 49_500_000, now=0.0)
    for c in IDS[:-1]:
        b.offer(c, 49_500_000, c)
    assert b.to_ask() == []
    assert b.poll(0.6) is Action.TIMEOUT
    missing, absent = b.expire()
    assert (missing, absent) == ([IDS[-1]], [])
    assert b.waiting and b.faults[IDS[-1]] == 1 and b.faults["trip"] == 0
    assert b.to_ask() == ["trip"]
    assert b.poll(0.7) is Action.NONE  # the timer restarted at 0.6
    assert b.poll(1.2) is Action.TIMEOUT
    assert b.expire() == (["trip"], [])
    assert not b.waiting and b.faults["trip"] == 1
    assert IDS[-1] not in b.got  # its answer counts as none


def test_late_answer_of_a_missed_controller_does_not_reopen_the_sample() -> None:
    b = _last_barrier()
    b.begin(99, 49_500_000, now=0.0)
    for c in IDS[:-1]:
        b.offer(c, 49_500_000, c)
    b.poll(0.6)
    b.expire()
    b.to_ask()
    assert not b.offer(IDS[-1], 49_500_000, "late")
    assert b.missing() == ["trip"] and IDS[-1] not in b.got  # it missed the sample
    assert b.offer("trip", 49_500_000)
