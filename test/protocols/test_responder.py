"""Stamp responder: a repeat gets the cached answer, an older stamp is dropped."""

from __future__ import annotations

from dcsms_ros.protocols.responder import StampResponder, Verdict


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
