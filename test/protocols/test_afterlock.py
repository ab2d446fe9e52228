"""The calls a host runs once it released a node's lock (protocols/afterlock.py)."""

from __future__ import annotations

from dcsms_ros.protocols.afterlock import AfterLock


def test_a_call_outside_a_host_callback_runs_at_once() -> None:
    later = AfterLock()
    ran: list[str] = []
    later.after(lambda: ran.append("now"))
    assert ran == ["now"]
    assert not later.holding
    assert later.release() == []


def test_calls_during_a_host_callback_wait_for_the_release_in_order() -> None:
    later = AfterLock()
    ran: list[int] = []
    later.hold()
    assert later.holding
    for i in range(3):
        later.after(lambda i=i: ran.append(i))
    assert ran == []  # nothing ran under the lock
    queued = later.release()
    assert not later.holding
    assert ran == []  # the host runs them, once the lock is free
    for fn in queued:
        fn()
    assert ran == [0, 1, 2]
    later.after(lambda: ran.append(9))  # queueing ended with the release
    assert ran == [0, 1, 2, 9]


def test_each_hold_starts_an_empty_queue() -> None:
    later = AfterLock()
    later.hold()
    later.after(lambda: None)
    assert len(later.release()) == 1
    later.hold()
    assert later.release() == []
