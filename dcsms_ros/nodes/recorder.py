"""Recorder node: serialized subscriptions to the graph's topics, written to a rosbag2 bag.

Topics and their types are discovered from the graph (every ``discovery_period_s``), so topics
that appear late are recorded too. Each subscription asks for the QoS its publishers offer, as
``ros2 bag record`` does: reliable if every publisher is reliable, transient local if every
publisher is (so the latched ``/dcsms/mode`` and ``/dcsms/config`` published before the recorder
started are recorded), history keep-last ``queue_depth`` (:data:`DEFAULT_DEPTH`).

Messages are never deserialised: the callback receives the CDR bytes (``raw=True``) and hands
them to :class:`~dcsms_ros.analysis.bagio.BagWriter` with the DDS receive time as the bag time
(what ``ros2 bag record`` logs). In a composed process (``dcsms up --recorder composed``) a
topic written in the same process is taken from the process's bus instead
(:mod:`dcsms_ros.protocols.localbus`): the bytes as published, every message (no DDS queue to
overflow), its publication time as the bag time, on the driver thread after the control path;
its DDS reader stays (the graph shows the recorder) but is never read. Composed, the bag is
written by a bag writer process (:mod:`dcsms_ros.analysis.bagprocess`): the driver thread
only frames the bus's batches into its pipe, and that process writes them and counts the
bus's topics (their counters join the others when the bag closes). The recorder only reads
the header stamp of stamped types (:func:`dcsms_ros.cdr.read_stamp`) for the time-gap check
(:mod:`dcsms_ros.analysis.gaps`).

``/clock`` is not recorded by default (default ``topics`` is ``/dcsms/*``): at 2 kHz it only
duplicates the header stamps every ``/dcsms`` topic carries and would cost ~7 % of the
recorder's budget; name it in ``topics`` to record it.

Shutdown (SIGINT, SIGTERM or ``duration_s``): rclpy's own signal handlers are not installed
(they would invalidate the context before the queues are read); a Python handler sets a flag
(:func:`~dcsms_ros.ros.context.ros_context` with ``signals=True``), the spin loop ends, and
:meth:`Recorder.drain` takes everything still queued in the DDS readers until every active
topic shows a message received after the signal, or no message arrived for ``QUIET_S``, or
``DRAIN_MAX_S`` passed. Then the bag is closed (``metadata.yaml``) and renamed
into place: nothing received before the signal is lost.

Parameters: ``out`` (bag directory), ``topics`` (names or fnmatch patterns, default
``["/dcsms/*"]``), ``exclude`` (names or patterns not to record, default none: ``dcsms up``
leaves out the per-sample topics its node processes record themselves), ``storage`` (mcap |
sqlite3), ``queue_depth`` (4000), ``duration_s`` (0 = until a signal), ``report_period_s``
(10), ``discovery_period_s`` (0.5).
"""

from __future__ import annotations

import fnmatch
import sys
import time
from collections.abc import Sequence
from typing import Any

from rclpy.node import Node

from dcsms_ros.analysis.bagio import BagWriter, new_writer
from dcsms_ros.analysis.bagprocess import ProcessBagWriter
from dcsms_ros.analysis.gaps import PUBLISHED_KEY, Recording, TopicStats, published_json
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.cdr import read_stamp
from dcsms_ros.errors import BagError, DcsmsError
from dcsms_ros.nodes.recorder_topics import is_stamped, msg_class, qos_yaml, subscription_qos
from dcsms_ros.protocols.localbus import Sink
from dcsms_ros.ros.callbackgroups import DetachedGroup
from dcsms_ros.ros.connectivity import has_reader
from dcsms_ros.ros.context import STOP_EXCEPTIONS, ros_context, spin_until
from dcsms_ros.ros.executor import HostExecutor
from dcsms_ros.ros.gilfree import count_publishers, topic_names_and_types
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.hotpath import DrivenContext
from dcsms_ros.ros.housekeeping import Housekeeper
from dcsms_ros.ros.transport import widen_udp_receive_buffers

NODE_NAME = "dcsms_recorder"
DEFAULT_TOPICS = ("/dcsms/*",)
#: Drain ends once no message arrived for this long (s) ...
QUIET_S = 0.1
#: ... or after this long (s) at most: a backlog (a fast lockstep run recorded on a loaded
#: machine) is written to its end while messages keep coming out of the queues.
DRAIN_MAX_S = 30.0
#: Reader history per topic: 2 s at 2 kHz of CPU starvation absorbed without a drop (~0.2 MB
#: per topic of TwistStamped).
DEFAULT_DEPTH = 4000
#: How often (s) the executor writes the bag's full chunks: at 22,000 messages/s a 4 MB chunk
#: fills in ~1.8 s, so at most one waits at a time.
FLUSH_PERIOD_S = 0.25
#: Messages one callback takes from its subscription's queue at most (fairness bound).
GREEDY = 256


class Recorder(GraphNode):
    """Record matching topics into a new bag.

    Parameters
    ----------
    out, topics, storage, duration_s, queue_depth, exclude : optional
        Override the ROS parameters of the same name (used by ``dcsms record``).
    lossless : bool
        Composed: wait for the bag writer process when it falls behind (lockstep) rather than
        drop and count (real time; :mod:`dcsms_ros.analysis.bagprocess`).
    writer_cpus : frozenset of int, optional
        Composed: the CPUs of the bag writer process (None: the caller's).
    **kwargs
        Passed to :class:`rclpy.node.Node` (e.g. ``context``).

    Raises
    ------
    BagError
        If the bag cannot be created (exists already, bad storage).
    """

    def __init__(self, out: str | None = None, topics: Sequence[str] | None = None,
                 storage: str | None = None, duration_s: float | None = None,
                 queue_depth: int | None = None, exclude: Sequence[str] | None = None,
                 lossless: bool = True, writer_cpus: frozenset[int] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        p = self.declare_parameter
        self.out = out or str(p("out", "dcsms_bag").value)
        self.patterns = list(topics or p("topics", list(DEFAULT_TOPICS)).value)
        self.exclude = list(exclude or p("exclude", [""]).value)
        self.storage = storage or str(p("storage", "mcap").value)
        dur = p("duration_s", 0.0).value if duration_s is None else duration_s
        self.duration_s = float(dur or 0.0)
        self.depth = int(queue_depth or p("queue_depth", DEFAULT_DEPTH).value)
        report_s = float(p("report_period_s", 10.0).value)
        discovery_s = float(p("discovery_period_s", 0.5).value)
        ctx = self.context
        self.bus = ctx.bus if isinstance(ctx, DrivenContext) else None
        # composed, the bag is written by another process: the driver thread only frames the
        # bus's batches into a pipe (analysis/bagprocess.py); alone, chunks are compressed and
        # written by this node's executor (FLUSH_PERIOD_S), never in a write
        self.writer: BagWriter | McapBagWriter | ProcessBagWriter = (
            ProcessBagWriter(self.out, self.storage, lossless, cpus=writer_cpus)
            if self.bus is not None
            else new_writer(self.out, self.storage, defer_flush=True))
        self.stats: dict[str, TopicStats] = {}
        self._skipped: set[str] = set()
        self._subs: list[Any] = []
        # composed, the executor and the driver thread both write the bag (a thread-safe
        # writer); the bus's topics are counted by the bag writer process
        #: the topics written in this process, taken from the bus in batches
        self._sink = Sink(self._write_batch)
        self._from_bus = 0  # messages taken from the bus so far
        self._open = True
        self._t_start = time.monotonic()
        self._reported = (0, self._t_start, 0)
        self.discover()
        self.housekeeping(discovery_s, self.discover)
        self.housekeeping(FLUSH_PERIOD_S, self.writer.flush)
        if report_s > 0:
            self.housekeeping(report_s, self._report)

    # -- discovery ------------------------------------------------------------------------

    def _wanted(self, topic: str) -> bool:
        return any(fnmatch.fnmatchcase(topic, pat) for pat in self.patterns) and \
            not any(fnmatch.fnmatchcase(topic, pat) for pat in self.exclude if pat)

    def discover(self) -> None:
        """Subscribe to the wanted topics that have publishers now (also every
        ``discovery_period_s``; a composed host calls it once its nodes exist, so the
        recorder observes their topics from their first message on)."""
        # both graph queries release the GIL: rclpy's held it ~0.4 ms a discovery (gilfree)
        for topic, types in topic_names_and_types(self):
            if topic in self._skipped or not self._wanted(topic):
                continue
            if topic in self.stats:  # several publishers: their numbers and stamps interleave
                # the count only: the full endpoint infos cost ~0.2 ms a topic, and every
                # executor wake-up composed takes the GIL from the real-time driver thread
                self.stats[topic].set_publishers(count_publishers(self, topic))
                continue
            infos = self.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            if len(types) != 1:
                self._skip(topic, f"several types {types}")
                continue
            self._subscribe(topic, types[0], [i.qos_profile for i in infos])

    def _skip(self, topic: str, why: str) -> None:
        self._skipped.add(topic)
        self.get_logger().warning(f"not recording {topic}: {why}")

    def _subscribe(self, topic: str, msgtype: str, offered: list[Any]) -> None:
        local = self.bus is not None and self.bus.has_publisher(topic)
        if isinstance(self.writer, ProcessBagWriter):
            self.writer.wait_ready()  # the bag's own error (it exists) is not the topic's
        tid = -1  # the topic's id in the bag writer process
        try:
            cls = msg_class(msgtype)
            stamped = is_stamped(cls, msgtype)
            if isinstance(self.writer, ProcessBagWriter):
                tid = self.writer.add_topic(topic, msgtype, qos_yaml(offered), local, stamped)
            else:
                self.writer.add_topic(topic, msgtype, qos_yaml(offered))
        except (ImportError, AttributeError, ValueError, BagError) as exc:
            self._skip(topic, str(exc))
            return
        st = TopicStats(topic, msgtype, stamped, checked=len(offered) <= 1,
                        publishers=lambda: count_publishers(self, topic))
        self.stats[topic] = st
        qos = subscription_qos(offered, self.depth)
        holder: list[Any] = []
        if self.bus is not None and local:
            # before the DDS reader exists: the writers' first-sample gate waits for that
            self.bus.observe(topic, self._sink, tid)
            self.bus.add_reader(topic)
            # never read: keep-last 1 holds the DDS copies a remote reader causes
            holder.append(self.create_subscription(cls, topic, lambda m: None,
                                                   subscription_qos(offered, 1), raw=True,
                                                   callback_group=DetachedGroup()))
        else:
            holder.append(self.create_subscription(
                cls, topic, self._callback(topic, st, holder), qos, raw=True))
        self._subs.append(holder[0])
        self.get_logger().info(
            f"recording {topic} [{msgtype}] ({qos.reliability.name.lower()}, "
            f"{qos.durability.name.lower()}{', in process' if local else ''})")

    def _write_batch(self, batch: list[tuple[int, bytes, int, int]]) -> None:
        """The bus's messages of topics written in this process, ``(tag, data, seq, t_ns)``
        in publication order, ``tag`` the topic's id in the bag writer process."""
        if self._open:  # not published after the bag was closed
            assert isinstance(self.writer, ProcessBagWriter)
            self.writer.write_frames(batch)
            self._from_bus += len(batch)

    def _callback(self, topic: str, st: TopicStats, holder: list[Any]) -> Any:
        """A raw callback with message info, ``cb(cdr_bytes, info)`` (rclpy passes ``info``
        when the callback takes two parameters). After the message the executor handed over
        it takes up to :data:`GREEDY` more queued ones of the same subscription directly, so
        one executor round trip (~50 us in rclpy) serves a burst instead of one message."""
        write = self.writer.write
        add = st.add
        stamped = st.stamped

        def one(data: bytes, info: dict[str, Any]) -> None:
            recv = info.get("received_timestamp") or time.time_ns()
            write(topic, recv, data)
            add(info.get("publication_sequence_number"), read_stamp(data) if stamped else None,
                recv)

        def cb(data: bytes, info: dict[str, Any]) -> None:
            one(data, info)
            n = 1
            sub = holder[0]
            with sub.handle:
                take, msg_type = sub.handle.take_message, sub.msg_type
                while n < GREEDY:
                    got = take(msg_type, True)
                    if got is None:
                        break
                    one(*got)
                    n += 1

        return cb

    # -- reporting and shutdown ------------------------------------------------------------

    @property
    def total(self) -> int:
        """Messages recorded so far, every topic (composed: the bus's as handed to the bag
        writer process, whose counters join :attr:`stats` when the bag closes)."""
        return self._from_bus + sum(s.count for s in list(self.stats.values()))

    def _report(self) -> None:
        """One throttled progress line (every ``report_period_s``)."""
        total, t_prev, gaps_prev = self._reported
        now = time.monotonic()
        gaps = sum(s.seq_gaps + s.time_gaps for s in self.stats.values())
        rate = (self.total - total) / max(now - t_prev, 1e-9)
        msg = (f"{self.total} messages on {len(self.stats)} topics, {rate:.0f} msg/s, "
               f"{gaps} gap(s)")
        if gaps > gaps_prev:
            self.get_logger().warning(msg + f" (+{gaps - gaps_prev} since the last report)")
        else:
            self.get_logger().info(msg)
        self._reported = (self.total, now, gaps)

    def expired(self) -> bool:
        """True once ``duration_s`` (> 0) of wall time has passed since the start."""
        return self.duration_s > 0 and time.monotonic() - self._t_start >= self.duration_s

    def drain(self, executor: Any, since_ns: int) -> None:
        """Take every message still queued (see the module notes); ``since_ns``: stop time."""
        active = [s for s in self.stats.values() if s.count and s.last_recv_ns > since_ns - 1e9]
        end = time.monotonic() + DRAIN_MAX_S
        quiet_since = time.monotonic()
        while time.monotonic() < end:
            before = self.total
            executor.spin_once(timeout_sec=QUIET_S / 4)
            now = time.monotonic()
            if self.total != before:
                quiet_since = now
                if all(s.last_recv_ns > since_ns for s in active):
                    break
            elif now - quiet_since >= QUIET_S:
                break

    def missing(self) -> list[str]:
        """Requested exact topic names (no wildcard) that never had a publisher."""
        return [p for p in self.patterns if not any(c in p for c in "*?[") and
                p not in self.stats]

    def finish(self) -> Recording:
        """Close the bag (metadata, rename into place) and return the counts and gaps."""
        self._open = False  # the bus's observers write no more
        for s in self.stats.values():
            s.finish()
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._subs.clear()
        # what was published, so a reader of the bag (and `dcsms up`'s summary) sees the loss
        self.writer.set_custom_data(PUBLISHED_KEY, published_json(list(self.stats.values())))
        path = self.writer.close()
        if isinstance(self.writer, ProcessBagWriter):
            self.stats.update(self.writer.stats)
            self._from_bus = 0
            if self.writer.dropped:
                self.get_logger().warning(
                    f"{self.writer.dropped} messages not recorded: the bag writer process fell "
                    "behind by more than its backlog")
        return Recording(str(path), list(self.stats.values()), self.missing())


def record(out: str, topics: Sequence[str] | None = None, storage: str | None = None,
           duration_s: float | None = None, args: list[str] | None = None,
           queue_depth: int | None = None, exclude: Sequence[str] | None = None) -> Recording:
    """Record until SIGINT, SIGTERM or ``duration_s``; returns the counts and gaps.

    Must run in the main thread (it installs the signal handlers; the previous ones are
    restored on return). Creates and shuts down its own rclpy context.

    Raises
    ------
    BagError
        The bag cannot be created or finished.
    """
    with ros_context(args, signals=True) as ros:
        node: Recorder | None = None
        try:
            node = rec = Recorder(out, topics, storage, duration_s, queue_depth, exclude,
                                  context=ros.context)
            widen_udp_receive_buffers()  # ~0.4 s of the full graph kept while off its core
            executor = HostExecutor(context=ros.context)
            Housekeeper(executor).keep(rec.jobs)  # flush, discovery and report on one timer
            executor.add_node(rec)
            spin_until(executor, lambda: bool(ros.stop) or rec.expired())
            node.drain(executor, ros.stop.at_ns or time.time_ns())
            return node.finish()
        except BaseException:
            if node is not None:  # keep what was received: a closed bag, not an aborted one
                try:
                    node.writer.close()
                except DcsmsError:
                    node.writer.abort()
            raise
        finally:
            if node is not None:
                ros.bound_teardown()  # the bag is closed (or aborted) by now
                node.destroy_node()


def recorder_ready(node: Node, topics: Sequence[str]) -> bool:
    """True when the recorder subscribes to every topic in ``topics`` (call from a node of the
    graph, e.g. the lockstep plant, before its first step so no sample is lost)."""
    return all(has_reader(node, t, NODE_NAME) for t in topics)


def main(args: list[str] | None = None) -> int:
    """``ros2 run dcsms_ros recorder --ros-args -p out:=BAG``: exit 0 after a signal."""
    try:
        report = record("", args=args if args is not None else sys.argv)
    except STOP_EXCEPTIONS:
        return 0
    except DcsmsError as exc:
        print(f"recorder: error: {exc}", file=sys.stderr)
        return 2
    print(report.text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
