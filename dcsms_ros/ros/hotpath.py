"""Hot path: the control-path subscriptions of a node, served by a thread of their own.

rclpy's executors rebuild a wait set over *every* entity of a node (6 parameter services, the
enable service, timers, the ``/clock`` subscription of ``use_sim_time``, ...) on each wake-up
and dispatch each callback through a task: ~0.1-0.2 ms of Python per message, the dominant cost
of a lockstep step (measured: ``bench/graph_bench.py``, docs/performance.md). Here a node's
per-sample subscriptions are created in a callback group that no executor ever waits on
(:class:`~.callbackgroups.DetachedGroup`); a :class:`~.hotloop.HotLoop` thread
(:mod:`.hotloop`) waits on a minimal wait set holding just those subscriptions and a stop guard
condition, takes every queued message with ``take_message`` and runs its handler under the
node's lock. Services, parameters, timers and ``/clock`` stay with the normal executor, which
wakes rarely.

One process per node: each node's :class:`HotPath` gets its own loop, and its per-sample
messages to and from the other processes of this host travel on host lanes (FIFOs,
:mod:`.hostlane`, :mod:`.laneinput`): the loop waits on its subscriptions' lanes, which the
writers' writes wake, and a writer publishes on DDS only for readers without a lane (a
recorder process, ``ros2 topic echo``, another host). Composed (several nodes on
one context, :mod:`dcsms_ros.nodes.container`): the host creates the nodes on a
:class:`DrivenContext`, whose :attr:`~DrivenContext.driver` loop serves the hot paths of every node
of the context, in one thread (the driver belongs to the context, not to the module: nothing to
register or forget). One sample cycles plant -> decoupling -> controllers -> plant through the
nodes' real publishers without a thread switch, and without DDS: a per-sample publisher of a
composed process (:meth:`HotPath.publisher`) hands its bytes to the in-process subscribers
through the context's :class:`~dcsms_ros.protocols.localbus.LocalBus`, which the driver
dispatches in publication order until nothing is left, and publishes on DDS only while a reader
outside the process is matched (:mod:`.intraprocess`: how duplicates are avoided, how remote
readers are told apart). Subscriptions of topics without an in-process writer are served from
DDS as in one process per node.

``DCSMS_HOT_PATH=0`` turns it off: the subscriptions are then ordinary executor subscriptions
with the same handlers. Subscriptions nobody serves per sample (observers such as the trip
monitor) can be created detached and emptied in batches (:meth:`HotPath.take`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Collection
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile
from rclpy.subscription import Subscription

from dcsms_ros.protocols.afterlock import AfterLock
from dcsms_ros.protocols.localbus import Endpoint, Inbox, LocalBus
from dcsms_ros.ros.callbackgroups import DetachedGroup
from dcsms_ros.ros.detached import DetachedReaders
from dcsms_ros.ros.hostlane import LaneReader
from dcsms_ros.ros.hotloop import (
    GIL_SWITCH_S,
    IDLE_S,
    DrivenContext,
    HostedContext,
    HotLoop,
    enabled,
)
from dcsms_ros.ros.intraprocess import BusPublisher, DirectPublisher, HotPublisher
from dcsms_ros.ros.laneinput import lanes_for


class HotPath(DetachedReaders):
    """The per-sample subscriptions of ``node`` (and an optional tick).

    Parameters
    ----------
    node : Node
        Owner of the subscriptions (they are its entities: graph introspection and
        ``destroy_node`` see them as usual).
    lock : threading.Lock or RLock, optional
        Held while a handler (or ``tick``) runs; the node's executor callbacks that touch the
        same state take it too (:attr:`lock`). Default: a new RLock, so a node file needs no
        threading of its own.
    """

    def __init__(self, node: Node, lock: Any = None) -> None:
        self.node = node
        self.lock = lock if lock is not None else threading.RLock()
        self.on = enabled()
        self._group = DetachedGroup()
        self.subs: list[tuple[Subscription, Callable[[Any], None]]] = []
        #: every reader (subscribed or detached) and per-sample writer of the path, for
        #: :meth:`unmatched` and the readiness announcement (:mod:`.readiness`)
        self.readers: list[Subscription] = []
        self.writers: list[HotPublisher] = []
        self._tick: Callable[[], float | None] | None = None
        #: the tick's deadline only moves later (:meth:`set_tick`)
        self.lazy_tick = False
        #: the tick reads :attr:`woke_late_s` and :meth:`take_paused_s` (:meth:`set_tick`)
        self.timed_tick = False
        self.loop: HotLoop | None = None
        self._own = False
        self.messages = 0
        context = node.context
        #: The process's in-process bus (composed, path on), else None.
        self.bus: LocalBus | None = (context.bus if self.on and isinstance(
            context, DrivenContext) else None)
        self._inboxes: dict[Subscription, Inbox] = {}
        #: each reader's topic (rclpy's ``topic_name`` asks rcl: for every force reader at every
        #: plant tick, composed real time 256-271 us of driver CPU a sample against 268-273)
        self._topic_of: dict[Subscription, str] = {}
        self._served: list[tuple[Subscription, Callable[[Any], None]]] = []
        #: per served subscription: handle, message type, raw, handler, flush (read once, not
        #: per take)
        self._takes: list[tuple[Any, Any, bool, Callable[[Any], None],
                                Callable[[], None] | None]] = []
        self._flush: dict[Subscription, Callable[[], None] | None] = {}
        self._asked: dict[Subscription, tuple[Any, str, Callable[[Any], None], QoSProfile]] = {}
        self._replaced: dict[Subscription, Subscription] = {}
        #: what an executor callback sends once the host released the lock (reports)
        self.later = AfterLock()
        #: One process per node: per-sample messages between processes of this host go on
        #: lanes (:mod:`.hostlane`), DDS only for the others.
        self.lanes = lanes_for(node) if self.on and self.bus is None else None

    @property
    def error(self) -> BaseException | None:
        """The exception that ended the serving loop, if any."""
        return self.loop.error if self.loop is not None else None

    @property
    def woke_late_s(self) -> float:
        """How late the loop serving this path ran after its last wait while nothing of its
        process ran (s; 0 when it woke in time, when no path of the loop has a ``timed``
        tick, or the path is not served by a loop): :attr:`.hotloop.HotLoop.woke_late_s`."""
        return self.loop.woke_late_s if self.loop is not None else 0.0

    def take_paused_s(self) -> float:
        """How long, since the last call, the loop serving this path worked while nothing of
        its process ran (s; 0 as for :attr:`woke_late_s`):
        :meth:`.hotloop.HotLoop.take_paused_s`. From the path's tick only."""
        return self.loop.take_paused_s() if self.loop is not None else 0.0

    @property
    def driven(self) -> bool:
        """True when a composed process's driver loop serves this path."""
        return self.loop is not None and not self._own

    def subscribe(self, msg_type: Any, topic: str, handler: Callable[[Any], None],
                  qos: QoSProfile, raw: bool = False,
                  flush: Callable[[], None] | None = None) -> Subscription:
        """A subscription served by the hot loop (or by the executor when the path is off);
        ``raw``: the handler gets the serialized bytes (see :mod:`dcsms_ros.cdr`);
        ``flush``: called after the handler has had every message queued at a wake-up (after
        each one where messages come one at a time: in-process, or from the executor), so a
        node that must read every sample can answer only the newest."""
        each = handler if flush is None else _then(handler, flush)
        if not self.on:
            plain = self.node.create_subscription(msg_type, topic, each, qos, raw=raw)
            self.readers.append(plain)
            return plain
        lane = self._lane_reader(topic, raw)
        sub = self._reader(msg_type, topic, handler, qos, raw)
        self.readers.append(sub)
        self.subs.append((sub, handler))
        self._flush[sub] = flush
        latest = (isinstance(qos, QoSProfile) and qos.history == HistoryPolicy.KEEP_LAST
                  and qos.depth == 1)
        if self.bus is not None and raw:
            # keep-last 1 (real time): the newest sample only, as its DDS reader would keep
            self._local(sub.topic_name, each, latest)
        if self.lanes is not None and lane is not None:
            self.lanes.serve_input(sub, lane, handler, flush, latest)
        return sub

    def _lane_reader(self, topic: str, raw: bool) -> LaneReader | None:
        """The lane of a subscription to ``topic`` about to be made (raw, with lanes)."""
        return (self.lanes.reader(self.node.resolve_topic_name(topic))
                if self.lanes is not None and raw else None)

    def _reader(self, msg_type: Any, topic: str, handler: Callable[[Any], None],
                qos: QoSProfile, raw: bool) -> Subscription:
        """The DDS reader of a hot subscription. Composed, keep-last 1 until :meth:`resolve`
        (then ``qos`` if its topic has no in-process writer): a full history of unread samples
        makes every DDS publication cost more (depth 25,000: ~350 us instead of ~5 us)."""
        if self.bus is None or not raw:
            return self.node.create_subscription(msg_type, topic, handler, qos,
                                                 callback_group=self._group, raw=raw)
        shallow = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                             reliability=qos.reliability, durability=qos.durability)
        sub = self.node.create_subscription(msg_type, topic, handler, shallow,
                                            callback_group=self._group, raw=raw)
        self._asked[sub] = (msg_type, topic, handler, qos)
        return sub

    def _local(self, topic: str, handler: Callable[[bytes], None] | None,
               latest_only: bool = False) -> Endpoint:
        """The bus endpoint of one of this node's subscriptions (its DDS reader counted as
        this process's own); it is the one served if the topic has an in-process writer."""
        assert self.bus is not None
        self.bus.add_reader(topic)
        if handler is None:
            return self.bus.inbox(topic)
        return self.bus.subscribe(topic, handler, self.lock, latest_only)

    def publisher(self, msg_type: Any, topic: str, qos: QoSProfile) -> HotPublisher:
        """A per-sample publisher (serialized messages): composed, a :class:`BusPublisher`
        (in-process delivery, DDS only for remote readers); else a :class:`DirectPublisher`."""
        pub = self.node.create_publisher(msg_type, topic, qos)
        if self.bus is not None:
            out: HotPublisher = BusPublisher(pub, self.bus)
        else:
            # a transient-local writer's late readers get its history from DDS, not a lane
            lane = (self.lanes.writer(pub.topic_name) if self.lanes is not None and
                    qos.durability != DurabilityPolicy.TRANSIENT_LOCAL else None)
            out = DirectPublisher(pub, lane)
        self.writers.append(out)
        return out

    def served_from_dds(self, sub: Subscription) -> bool:
        """True if ``sub``'s messages come from DDS: no in-process writer of its topic, or
        it takes message objects (the bus carries serialized ones; such a reader is not
        counted as the process's own, so the writer publishes on DDS for it)."""
        if self.bus is None or not sub.raw:
            return True
        topic = self._topic_of.get(sub)
        if topic is None:
            topic = self._topic_of[sub] = sub.topic_name
        return not self.bus.has_publisher(topic)

    def unmatched(self, wanted: Collection[str] | None = None) -> list[str]:
        """Topics (those in ``wanted``, default every one) of the path's readers that take
        from DDS and whose reader has matched no writer yet; a reader served in process is
        matched. The reader's own count: a writer may have matched it before it matched the
        writer, and until it does it drops the writer's samples. A reader with a lane is
        matched once its writers said hello there too (:meth:`.LaneInput.ready`); first the
        path's writers open lanes to the readers found since (:meth:`.PathLanes.connect`)."""
        lanes = self.lanes.connect() if self.lanes is not None else {}
        out: list[str] = []
        now = time.monotonic()
        for asked in self.readers:
            sub = self._replaced.get(asked, asked)
            if wanted is not None and sub.topic_name not in wanted:
                continue
            lane = lanes.get(sub)
            if lane is not None:
                if not lane.ready(now):
                    out.append(sub.topic_name)
            elif self.served_from_dds(sub) and sub.get_publisher_count() == 0:
                out.append(sub.topic_name)
        if self.lanes is not None and self.lanes.pending():
            self.wake()  # what the check read off a lane waits for the hot loop
        return out

    def resolve(self) -> list[Subscription]:
        """Choose the subscriptions :meth:`serve` takes from (those of topics without an
        in-process writer, recreated with the QoS asked for) and return them; called before
        the loop starts, once every writer of the process exists."""
        for old, (msg_type, topic, handler, qos) in list(self._asked.items()):
            if self.served_from_dds(old):
                new = self.node.create_subscription(msg_type, topic, handler, qos,
                                                    callback_group=self._group, raw=True)
                self.node.destroy_subscription(old)
                self._replaced[old] = new
                self.subs = [(new if s is old else s, h) for s, h in self.subs]
                self._flush[new] = self._flush.pop(old, None)
        self._asked.clear()
        self._served = [(s, h) for s, h in self.subs if self.served_from_dds(s)]
        # a subscription with a lane is read by its LaneInput (the lane, and DDS when needed)
        self._takes = [(s.handle, s.msg_type, s.raw, h, self._flush.get(s))
                       for s, h in self._served
                       if self.lanes is None or s not in self.lanes.inputs]
        return [s for s, _ in self._served]

    @property
    def ticking(self) -> bool:
        """True if :meth:`set_tick` gave the path a tick."""
        return self._tick is not None

    def set_tick(self, tick: Callable[[], float | None], lazy: bool = False,
                 timed: bool = False) -> None:
        """Call ``tick()`` (under the lock) after every wake-up; it returns the longest wait
        (s) until it must run again, or None for :data:`IDLE_S`. Only with the path on, and
        before it starts.

        ``lazy``: the tick's deadline never comes sooner than it said (a handler or another
        thread only moves it later, or calls :meth:`wake`), so the loop calls it only once
        the wait it returned has passed, or after a :meth:`wake`: a controller's watchdog,
        which each input moves later. Asked at every wake-up it was the lock and three calls
        a sample (docs/performance.md, "Fewer calls a sample").

        ``timed``: the tick reads :attr:`woke_late_s` and :meth:`take_paused_s` (the plant's
        pacer), so the loop reads the process's CPU time around each wait, ~1-2 us a wake-up
        that a controller's 40 us budget need not pay (a loop without a timed path reports
        0)."""
        self._tick = tick
        self.lazy_tick = lazy
        self.timed_tick = timed

    def start(self) -> None:
        """Serve the subscriptions: by this process's driver loop if the node's context is
        a :class:`DrivenContext` (composed), else by a thread of its own (no-op when off, when
        already started, without subscriptions and tick, or while a :class:`HostedContext`
        is held: its host starts the loop)."""
        if not self.on or self.loop is not None or not (self.subs or self._tick):
            return
        context = self.node.context
        if isinstance(context, HostedContext) and context.held:
            return
        if isinstance(context, DrivenContext):
            self.loop = context.driver
            context.driver.add(self)
            return
        self.loop = HotLoop(self.node.context, f"hot-{self.node.get_name()}")
        self._own = True
        self.loop.add(self)
        self.loop.start()

    def wake(self) -> None:
        """Make the loop run the ticks now (e.g. when stepping starts)."""
        if self.loop is not None:
            self.loop.wake()

    def stop(self, timeout_s: float = 2.0) -> None:
        """End this node's own loop and wait for it (idempotent; a driver loop is stopped by
        its process)."""
        if self.loop is not None and self._own:
            self.loop.stop(timeout_s)

    def serve(self) -> int:
        """Take every queued message of the subscriptions and run the handlers under the
        lock; returns how many."""
        n = 0
        with self.lock:
            for h, typ, raw, handler, flush in self._takes:
                n0 = n
                while True:
                    got = h.take_message(typ, raw)
                    if got is None:
                        break
                    n += 1
                    handler(got[0])
                if flush is not None and n > n0:
                    flush()
            if self.lanes is not None:
                n += self.lanes.serve()
        self.messages += n
        return n

    def lane_fds(self) -> list[int]:
        """The FIFOs of the served subscriptions' lanes (the hot loop waits on them)."""
        return self.lanes.fds() if self.lanes is not None else []

    def lane_state(self, now: float) -> str:
        """How the hot loop must wait (:meth:`.PathLanes.state`; ``now``: monotonic s)."""
        return self.lanes.state(now, len(self._served)) if self.lanes is not None else "dds"

    def close_lanes(self) -> None:
        """Say bye on the writers' lanes and remove the readers' (the node is going); log,
        per writer, how its messages went."""
        if self.lanes is None:
            return
        for w in self.writers:
            if isinstance(w, DirectPublisher) and w.lane is not None:
                t = w.lane.table
                self.node.get_logger().info(
                    f"lanes: {w.lane.topic}: {t.sent} messages on lanes, {w.on_dds} on DDS "
                    f"({w.on_dds_after_leave} after a lane's reader left), {t.drops} lost on "
                    "full lanes")
        self.lanes.close()

    def tick(self) -> float | None:
        """Run the tick under the lock (None without one)."""
        if self._tick is None:
            return None
        with self.lock:
            return self._tick()


def _then(handler: Callable[[Any], None], flush: Callable[[], None]) -> Callable[[Any], None]:
    """``handler`` followed by ``flush`` for each message."""
    def each(msg: Any) -> None:
        handler(msg)
        flush()
    return each


__all__ = ["GIL_SWITCH_S", "IDLE_S", "DrivenContext", "HotLoop", "HotPath", "enabled"]
