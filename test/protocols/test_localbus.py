"""The in-process bus without DDS: order, exactly-once delivery, observers, counts, remote."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from dcsms_ros.protocols.localbus import LocalBus, Sink


class Ticks:
    """A fake clock: 1000, 2000, ... ns."""

    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        self.t += 1000
        return self.t


def _cycle(bus: LocalBus, steps: int, log: list[tuple[str, bytes]]) -> None:
    """A lockstep cycle plant -> decoupling -> two controllers -> plant, ``steps`` samples."""
    raw, vel = bus.advertise("/raw"), bus.advertise("/vel")
    forces = {c: bus.advertise(f"/force/{c}") for c in ("a", "b")}
    got: dict[int, set[str]] = {}

    def plant(c: str, data: bytes) -> None:
        log.append((f"plant<{c}", data))
        k = int(data)
        got.setdefault(k, set()).add(c)
        if got[k] == {"a", "b"} and k + 1 < steps:
            raw.publish(b"%d" % (k + 1))

    def decoupling(data: bytes) -> None:
        log.append(("dec", data))
        vel.publish(data)

    bus.subscribe("/raw", decoupling)
    for c, w in forces.items():
        bus.subscribe("/vel", lambda d, c=c, w=w: (log.append((c, d)), w.publish(d)))
        bus.subscribe(f"/force/{c}", lambda d, c=c: plant(c, d))
    raw.publish(b"0")


def test_lockstep_cycle_is_delivered_in_publication_order_without_recursion() -> None:
    """1,000 samples of a cycle whose handlers publish the next message: one dispatch loop (no
    recursion), every handler once per sample, in publication order."""
    bus = LocalBus(clock=Ticks())
    log: list[tuple[str, bytes]] = []
    _cycle(bus, 1000, log)
    total = 0
    while bus.pending:
        total += bus.dispatch(limit=300)  # bounded rounds, as the driver loop runs them
    assert total == 1000 * 4  # raw, vel, two forces per sample
    first = [name for name, _ in log[:6]]
    assert first == ["dec", "a", "b", "plant<a", "plant<b", "dec"]
    for name in ("dec", "a", "b", "plant<a", "plant<b"):
        seen = [int(d) for n, d in log if n == name]
        assert seen == list(range(1000)), name
    assert bus.published("/raw") == bus.published("/vel") == 1000


@pytest.mark.parametrize("per_topic", [1, 2])
@pytest.mark.parametrize("batch", [1, 5, 64])
def test_observers_get_every_message_once_in_order_after_the_control_path(
        batch: int, per_topic: int) -> None:
    """Each sink observing every topic (one, the recorder, or two) sees each message once, with
    its writer's sequence number 1, 2, ... and its publication time, in publication order
    across its topics, a batch per call; at most ``batch`` deliveries wait behind handlers."""
    clock = Ticks()
    bus = LocalBus(clock=clock, observer_batch=batch)
    log: list[tuple[str, bytes]] = []
    seen: dict[tuple[str, int], list[tuple[bytes, int, int]]] = {}
    order: dict[int, list[int]] = {}
    calls: dict[int, int] = {}
    waiting: list[int] = []
    topics = ("/raw", "/vel", "/force/a", "/force/b")

    def sink_of(i: int) -> Sink:
        def take(items: list[tuple[Any, bytes, int, int]]) -> None:
            calls[i] = calls.get(i, 0) + 1
            for tag, d, s, ns in items:
                seen.setdefault((tag, i), []).append((d, s, ns))
                order.setdefault(i, []).append(ns)
        return Sink(take)

    sinks = [sink_of(i) for i in range(per_topic)]
    for t in topics:
        for i in range(per_topic):
            bus.observe(t, sinks[i], t)
    _cycle(bus, 200, log)
    bus.subscribe("/raw", lambda d: waiting.append(bus.backlog))
    while bus.pending:
        bus.dispatch()
    assert sorted(seen) == sorted((t, i) for t in topics for i in range(per_topic))
    for k, got in seen.items():
        assert [d for d, _, _ in got] == [b"%d" % n for n in range(200)], k
        assert [s for _, s, _ in got] == list(range(1, 201)), k
        stamps = [ns for _, _, ns in got]
        assert stamps == sorted(stamps) and len(set(stamps)) == 200
    for i, sink in enumerate(sinks):
        assert order[i] == sorted(order[i]) and sink.delivered == 800  # publication order
        # one call per batch (the cycle runs in one dispatch): a call each time ``batch``
        # deliveries of all sinks wait, and one for the rest
        assert calls[i] <= -(-800 * per_topic // batch) + 1
    assert max(waiting) < batch  # a full batch is served before the next handler runs


def test_inbox_queues_with_publication_time_and_drains_in_blocks() -> None:
    """An inbox keeps (data, t_ns) until its owner drains it, oldest first, ``limit`` at a
    time; a handler of the same topic is not affected."""
    bus = LocalBus(clock=Ticks())
    w = bus.advertise("/applied")
    box = bus.inbox("/applied")
    calls: list[bytes] = []
    bus.subscribe("/applied", calls.append)
    for k in range(10):
        w.publish(b"%d" % k)
    bus.dispatch()
    assert calls == [b"%d" % k for k in range(10)]
    got: list[tuple[bytes, int]] = []
    assert box.drain(lambda d, t: got.append((d, t)), limit=4) == 4
    assert box.drain(lambda d, t: got.append((d, t))) == 6
    assert got == [(b"%d" % k, 1000 * (k + 1)) for k in range(10)]
    assert box.delivered == 10 and not box.queue
    for k in range(10, 15):
        w.publish(b"%d" % k)
    bus.dispatch()
    assert box.take(limit=2) == [b"10", b"11"]
    assert box.take() == [b"12", b"13", b"14"] and box.take() == []


def test_remote_counts_only_readers_outside_the_process() -> None:
    """With two DDS readers of this process on a topic, a writer matched to 2 has no remote
    reader, matched to 3 it has; a topic without own readers is remote at 1."""
    bus = LocalBus()
    raw = bus.advertise("/raw")
    bus.add_reader("/raw")
    bus.add_reader("/raw")
    assert [raw.remote(m) for m in (0, 1, 2, 3)] == [False, False, False, True]
    assert bus.has_publisher("/raw") and not bus.has_publisher("/other")
    other = bus.advertise("/other")
    assert other.remote(1) and not other.remote(0)


def test_publication_from_another_thread_wakes_the_dispatcher() -> None:
    """A message published by a thread other than the owner calls ``wake``; the owner's own
    publications do not."""
    wakes: list[int] = []
    bus = LocalBus(wake=lambda: wakes.append(threading.get_ident()))
    bus.owner = threading.get_ident()
    w = bus.advertise("/t")
    w.publish(b"own")
    th = threading.Thread(target=w.publish, args=(b"other",))
    th.start()
    th.join()
    assert len(wakes) == 1 and wakes[0] != bus.owner
    got: list[bytes] = []
    bus.subscribe("/t", got.append)
    bus.dispatch()
    assert got == [b"own", b"other"]


def test_handlers_run_under_their_lock() -> None:
    """Each call holds the endpoint's lock (another thread cannot take it meanwhile)."""
    lock = threading.Lock()
    held: list[bool] = []
    bus = LocalBus()
    w = bus.advertise("/t")
    bus.subscribe("/t", lambda d: held.append(lock.locked()), lock)
    bus.observe("/t", Sink(lambda items: held.append(lock.locked()), lock))
    w.publish(b"x")
    bus.dispatch()
    assert held == [True, True] and not lock.locked()


def test_close_settles_the_queue_on_inboxes_and_observers_only() -> None:
    """After close no handler runs (its node is going); what was queued, and what is published
    later and settled by another close, still reaches the observers and inboxes."""
    bus = LocalBus()
    w = bus.advertise("/t")
    calls: list[bytes] = []
    seen: list[bytes] = []
    bus.subscribe("/t", calls.append)
    box = bus.inbox("/t")
    bus.observe("/t", Sink(lambda items: seen.extend(d for _, d, _, _ in items)))
    w.publish(b"1")
    assert bus.close() == 1
    w.publish(b"2")
    assert bus.dispatch() == 0  # closed: handlers are not called any more
    assert bus.close() == 1
    assert calls == [] and seen == [b"1", b"2"] and len(box.queue) == 2


def test_dispatch_limit_leaves_the_rest_queued() -> None:
    """``limit`` bounds one round; the rest is delivered by the next ones, nothing twice."""
    bus = LocalBus()
    w = bus.advertise("/t")
    got: list[bytes] = []
    bus.subscribe("/t", got.append)
    for k in range(25):
        w.publish(b"%d" % k)
    assert [bus.dispatch(limit=10) for _ in range(4)] == [10, 10, 5, 0]
    assert got == [b"%d" % k for k in range(25)] and not bus.pending


def test_latest_only_handler_skips_what_a_newer_message_replaces() -> None:
    """A burst of 5 samples published before a dispatch (a real-time catch-up): a keep-last-1
    handler gets the newest only and counts 4 skipped; a keep-all handler and an observer get
    all 5; a burst of 1 is never skipped."""
    bus = LocalBus()
    w = bus.advertise("/raw")
    newest: list[bytes] = []
    every: list[bytes] = []
    seen: list[bytes] = []
    ep = bus.subscribe("/raw", newest.append, latest_only=True)
    bus.subscribe("/raw", every.append)
    bus.observe("/raw", Sink(lambda items: seen.extend(d for _, d, _, _ in items)))
    for k in range(5):
        w.publish(b"%d" % k)
    bus.dispatch()
    w.publish(b"5")
    bus.dispatch()
    assert newest == [b"4", b"5"] and ep.skipped == 4 and ep.delivered == 2
    assert every == seen == [b"%d" % k for k in range(6)]
