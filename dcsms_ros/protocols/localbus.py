"""In-process delivery: serialized messages handed from a publisher to the subscribers of the
same process, without DDS (what rclcpp's intra-process communication does; rclpy has none).

A composed graph (every node in one process, one driver thread) publishes each per-sample
message through a :class:`BusWriter`; the driver calls :meth:`LocalBus.dispatch`, which hands
the bytes to the endpoints of the topic in publication order:

* **handlers** (:meth:`LocalBus.subscribe`): the control path, called at once (under the
  endpoint's lock). A handler may publish: its messages queue behind the current ones, so a
  lockstep cycle plant -> decoupling -> controllers -> plant runs without recursion. A
  ``latest_only`` handler (a real-time reader, keep-last 1) skips a message when a newer one of
  the topic is already queued, as its DDS reader's history would have replaced it.
* **inboxes** (:meth:`LocalBus.inbox`): a queue its owner empties when it likes (the trip
  checker's blocks, the real-time plant's held forces), each message with its publication time.
* **observers** (:meth:`LocalBus.observe`): a recorder, a :class:`Sink` of the topics it
  observes. A sink gets its messages in batches, in publication order, after the control
  path has nothing left to do, or once :data:`OBSERVER_BATCH` messages wait, so it never
  delays an answer by more than one batch and loses nothing (the queue is not bounded: a
  lockstep run waits for its observers as it waited for a reliable reader). One call per
  batch, not per message: a recorder of 11 topics took 1.6-2.0 us per message against
  2.2-2.4 with a call each (a microbenchmark, 2026-12-02; the composed lockstep graph,
  recorded, 4 same-run pairs: +0.2 to +6.5 %, within its noise).

Every endpoint gets every message once; a topic's DDS publication is the caller's business:
:meth:`BusWriter.remote` tells it (from the DDS writer's matched-reader count,
:mod:`.matched`, and the number of this process's own DDS readers, :meth:`LocalBus.add_reader`)
whether a reader outside the process is matched. Publications from another thread than the
dispatching one call ``wake``. No ROS here: unit-tested with plain callables
(test/protocols/test_localbus.py).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

#: Observer deliveries that may wait behind the control path (messages).
OBSERVER_BATCH = 64
#: Messages one :meth:`LocalBus.dispatch` delivers at most, so the driver still sees its stop
#: request and runs its ticks during an endless lockstep chain.
DISPATCH_LIMIT = 2000

@dataclass
class Endpoint:
    """One in-process subscriber of a topic.

    Attributes
    ----------
    topic : str
        Fully resolved topic name.
    handler : callable or None
        ``handler(data)`` (handlers); None for an inbox or an observer.
    lock : context manager or None
        Held around each call of ``handler``.
    latest_only : bool
        Handlers: skip a message when a newer one of the topic is queued.
    delivered : int
        Messages handed to this endpoint (not counted for an observer: its sink counts).
    skipped : int
        Messages skipped for a newer one (``latest_only``).
    """

    topic: str
    handler: Callable[..., None] | None = None
    lock: Any = None
    latest_only: bool = False
    delivered: int = 0
    skipped: int = 0


class Sink:
    """An observer of one or more topics: ``handler(batch)``, ``batch`` a list of
    ``(tag, data, seq, t_ns)`` in publication order (``tag``: the observing endpoint's,
    ``seq``: the writer's message number, ``t_ns``: publication time, the bus clock's ns).
    The batch is the handler's to keep.

    Parameters
    ----------
    handler : callable
    lock : context manager, optional
        Held around each call of ``handler``.
    """

    def __init__(self, handler: Callable[[list[tuple[Any, bytes, int, int]]], None],
                 lock: Any = None) -> None:
        self.handler = handler
        self.lock = lock
        self.items: list[tuple[Any, bytes, int, int]] = []
        #: Messages handed to the handler.
        self.delivered = 0


@dataclass
class Inbox(Endpoint):
    """A queue of ``(data, t_ns)`` (``t_ns``: publication time, the bus clock's ns) that its
    owner empties with :meth:`drain` or :meth:`take`."""

    queue: deque[tuple[bytes, int]] = field(default_factory=deque)

    def drain(self, handler: Callable[[bytes, int], None], limit: int = 100000) -> int:
        """Call ``handler(data, t_ns)`` for the queued messages, oldest first (at most
        ``limit``); returns how many."""
        q = self.queue
        n = 0
        while q and n < limit:
            data, t_ns = q.popleft()
            handler(data, t_ns)
            n += 1
        return n

    def take(self, limit: int = 100000) -> list[bytes]:
        """The queued messages' data, oldest first (at most ``limit``), taken off the queue
        (a block for a batch decoder: no call per message)."""
        q = self.queue
        return [q.popleft()[0] for _ in range(min(len(q), limit))]


@dataclass(kw_only=True)
class Observer(Endpoint):
    """One topic's messages queued for ``sink`` with ``tag`` (see :meth:`LocalBus.observe`);
    its sink counts what it was handed (:attr:`Sink.delivered`)."""

    sink: Sink
    tag: Any = None


@dataclass
class _Topic:
    """The endpoints of one topic (tuples, replaced whole: the dispatcher may be iterating)."""

    name: str
    handlers: tuple[Endpoint, ...] = ()
    inboxes: tuple[Inbox, ...] = ()
    observers: tuple[Observer, ...] = ()
    writers: int = 0
    readers: int = 0
    published: int = 0
    queued: int = 0


class BusWriter:
    """The in-process side of one publisher: numbers its messages 1, 2, ... as a DDS writer
    numbers its samples, and queues them on the bus."""

    def __init__(self, bus: LocalBus, topic: _Topic,
                 queue: deque[tuple[_Topic, bytes, int, int]]) -> None:
        self.bus = bus
        self.topic = topic
        self.seq = 0
        self._queue = queue

    @property
    def name(self) -> str:
        """The topic's fully resolved name."""
        return self.topic.name

    def remote(self, matched: int) -> bool:
        """True if this writer's DDS writer, matched with ``matched`` readers, has one outside
        this process (more readers than this process's own)."""
        return matched > self.topic.readers

    def publish(self, data: bytes) -> None:
        """Queue ``data`` (serialized) for every in-process endpoint of the topic."""
        self.seq += 1
        self.topic.published += 1
        self.topic.queued += 1
        bus = self.bus
        self._queue.append((self.topic, data, self.seq, bus.clock()))
        if bus.wake is not None and threading.get_ident() != bus.owner:
            bus.wake()


class LocalBus:
    """Topic -> in-process endpoints; delivery in publication order; counts.

    Parameters
    ----------
    clock : callable
        ``clock()`` -> int ns stamped on each message at publication (default: the system
        clock, the clock of DDS reception times).
    wake : callable, optional
        Called when a message is published from a thread other than :attr:`owner` (the
        dispatcher's), so the dispatcher wakes up.
    observer_batch : int
        Observer deliveries that may wait behind the control path.
    """

    def __init__(self, clock: Callable[[], int] = time.time_ns,
                 wake: Callable[[], None] | None = None,
                 observer_batch: int = OBSERVER_BATCH) -> None:
        self.clock = clock
        self.wake = wake
        self.observer_batch = observer_batch
        #: Thread ident of the dispatcher (publications from it need no wake-up).
        self.owner: int | None = None
        self._topics: dict[str, _Topic] = {}
        self._queue: deque[tuple[_Topic, bytes, int, int]] = deque()
        self._sinks: list[Sink] = []
        #: observer deliveries queued in the sinks
        self._waiting = 0
        self.closed = False

    def _topic(self, name: str) -> _Topic:
        t = self._topics.get(name)
        if t is None:
            t = self._topics[name] = _Topic(name)
        return t

    # -- endpoints ---------------------------------------------------------------------------
    def advertise(self, topic: str) -> BusWriter:
        """A writer of ``topic`` in this process."""
        t = self._topic(topic)
        t.writers += 1
        return BusWriter(self, t, self._queue)

    def has_publisher(self, topic: str) -> bool:
        """True if a writer of ``topic`` lives in this process (its in-process readers get the
        messages from the bus, not from DDS)."""
        t = self._topics.get(topic)
        return t is not None and t.writers > 0

    def subscribe(self, topic: str, handler: Callable[[bytes], None], lock: Any = None,
                  latest_only: bool = False) -> Endpoint:
        """A control-path endpoint: ``handler(data)`` for each message (the newest only with
        ``latest_only``), at once."""
        ep = Endpoint(topic, handler, lock, latest_only)
        t = self._topic(topic)
        t.handlers = (*t.handlers, ep)
        return ep

    def inbox(self, topic: str) -> Inbox:
        """A queued endpoint (see :class:`Inbox`)."""
        ep = Inbox(topic)
        t = self._topic(topic)
        t.inboxes = (*t.inboxes, ep)
        return ep

    def observe(self, topic: str, sink: Sink, tag: Any = None) -> Observer:
        """Queue every message of ``topic`` for ``sink`` with ``tag``, delivered after the
        control path (see the module notes); may be added while messages flow (it gets those
        published from then on)."""
        ep = Observer(topic, sink=sink, tag=tag)
        t = self._topic(topic)
        t.observers = (*t.observers, ep)
        if not any(x is sink for x in self._sinks):
            self._sinks = [*self._sinks, sink]
        return ep

    def add_reader(self, topic: str) -> None:
        """Count one DDS reader of ``topic`` in this process (see :meth:`BusWriter.remote`)."""
        self._topic(topic).readers += 1

    def published(self, topic: str) -> int:
        """Messages published on ``topic`` in this process."""
        t = self._topics.get(topic)
        return t.published if t is not None else 0

    # -- delivery ----------------------------------------------------------------------------
    @property
    def backlog(self) -> int:
        """Observer deliveries waiting behind the control path."""
        return self._waiting

    @property
    def pending(self) -> bool:
        """True while a message waits for delivery (control path or observers)."""
        return bool(self._queue) or self._waiting > 0

    def dispatch(self, limit: int = DISPATCH_LIMIT) -> int:
        """Deliver the queued messages (and those their handlers publish) in publication order,
        at most ``limit``; observers when the queue is empty or a batch waits. Returns the
        number of messages taken off the queue. A handler's exception propagates (the rest
        stays queued)."""
        q = self._queue
        n = 0
        while q and n < limit and not self.closed:
            topic, data, seq, t_ns = q.popleft()
            topic.queued -= 1
            n += 1
            for ep in topic.handlers:
                if ep.latest_only and topic.queued:
                    ep.skipped += 1
                    continue
                ep.delivered += 1
                assert ep.handler is not None
                if ep.lock is None:
                    ep.handler(data)
                else:
                    with ep.lock:
                        ep.handler(data)
            for box in topic.inboxes:
                box.delivered += 1
                box.queue.append((data, t_ns))
            observers = topic.observers
            if observers:
                for ob in observers:
                    ob.sink.items.append((ob.tag, data, seq, t_ns))
                self._waiting += len(observers)
                if self._waiting >= self.observer_batch:
                    self.flush_observers()
        if not q:
            self.flush_observers()
        return n

    def flush_observers(self) -> int:
        """Hand every sink its waiting batch; returns how many deliveries."""
        n, self._waiting = self._waiting, 0
        if not n:
            return 0
        for sink in self._sinks:
            batch = sink.items
            if not batch:
                continue
            sink.items = []
            sink.delivered += len(batch)
            if sink.lock is None:
                sink.handler(batch)
            else:
                with sink.lock:
                    sink.handler(batch)
        return n

    def close(self) -> int:
        """Stop calling handlers (their nodes are going) and hand what is still queued, and
        whatever is published from now on when this is called again, to the inboxes and
        observers only; returns the messages settled."""
        self.closed = True
        q = self._queue
        n = 0
        while q:
            topic, data, seq, t_ns = q.popleft()
            topic.queued -= 1
            n += 1
            for box in topic.inboxes:
                box.delivered += 1
                box.queue.append((data, t_ns))
            for ob in topic.observers:
                ob.sink.items.append((ob.tag, data, seq, t_ns))
            self._waiting += len(topic.observers)
        self.flush_observers()
        return n


__all__ = ["DISPATCH_LIMIT", "OBSERVER_BATCH", "BusWriter", "Endpoint", "Inbox", "LocalBus",
           "Observer", "Sink"]
