"""The rclpy side of in-process delivery (:mod:`dcsms_ros.protocols.localbus`).

In a composed process (:class:`~.hotpath.DrivenContext`) a per-sample publisher is a
:class:`BusPublisher`: each message goes to the in-process subscribers through the bus, and to
DDS only when DDS has a reader to give it to:

* **Duplicates.** An in-process subscriber of a topic with an in-process writer keeps its DDS
  reader (``ros2 node info``, the graph checks and the first-sample gate see the same graph as
  one process per node) but never reads it: the driver leaves it out of its wait set and the
  node's inbox is the bus's, so each message arrives once. The DDS copies that reader gets
  while a remote reader is matched are dropped by its keep-last history, unread.
* **Remote readers.** The DDS writer's matched-reader count (``get_subscription_count()``)
  minus this process's own readers of the topic (counted as they are created) is the number of
  readers outside the process: rclcpp's rule. The count is asked again at the first
  publication 1 ms after the last answer (:class:`~dcsms_ros.protocols.matched.MatchCount`),
  so a remote reader (``ros2 topic echo``, a recorder process, a probe) gets every message
  published from at most 1 ms after it matched, and nothing goes to DDS 1 ms after the last
  one left. Asked at every publication, the rmw call (~0.5 us in the composed process, ten
  publications per sample) was 3.6 % of the composed lockstep step (py-spy).
* **History.** A transient-local writer (the lockstep velocities and applied forces,
  :func:`~.qos.stream_pub` ``durable=True``) holds the newest messages of its depth that went
  to no DDS reader (:class:`~dcsms_ros.protocols.matched.HeldHistory`) and publishes them
  on DDS, oldest first, just before the first message a remote reader is matched for: a
  late-joining recorder gets the same history as from one process per node. (Publishing them
  on DDS all along cost ~20 us per message, 4 per lockstep sample: the DDS copies to this
  process's own readers.) A volatile remote reader that joins then gets that history too.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.duration import Duration
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy

from dcsms_ros.protocols.localbus import BusWriter, LocalBus
from dcsms_ros.protocols.matched import LANE_MATCH_REFRESH_NS, HeldHistory, MatchCount
from dcsms_ros.ros.hostlane import LaneWriter

#: A message an observer encodes itself: ``(encode, ns, value)``, its bytes
#: ``encode(ns, value)`` (:meth:`DirectPublisher.publish_later`).
Deferred = tuple[Callable[[int, Any], bytes], int, Any]


class _Wrapped:
    """What a per-sample publisher shares with rclpy's: name, handle, matches, acks."""

    pub: Publisher
    #: Whether an observer takes every message (:meth:`DirectPublisher.observe`), so the
    #: messages are wanted whoever else reads them.
    observed = False

    @property
    def topic_name(self) -> str:
        """The fully resolved topic name."""
        return str(self.pub.topic_name)

    @property
    def handle(self) -> Any:
        """The DDS publisher's handle."""
        return self.pub.handle

    def get_subscription_count(self) -> int:
        """The DDS writer's matched readers, this process's own included (as a plain
        publisher's: the graph checks compare it with the graph's reader count)."""
        return self.pub.get_subscription_count()

    def wait_for_all_acked(self, timeout: Duration) -> bool:
        """The DDS writer's wait for its reliable readers' acknowledgements."""
        return bool(self.pub.wait_for_all_acked(timeout))


class BusPublisher(_Wrapped):
    """A per-sample publisher of a composed process (see the module notes).

    Parameters
    ----------
    pub : Publisher
        The node's DDS publisher of the topic (created by the node as usual).
    bus : LocalBus
        The process's bus.
    """

    def __init__(self, pub: Publisher, bus: LocalBus) -> None:
        self.pub = pub
        self.bus = bus
        self.writer: BusWriter = bus.advertise(pub.topic_name)
        qos = pub.qos_profile
        self.held = (HeldHistory(qos.depth) if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
                     else None)
        #: Messages also published on DDS.
        self.on_dds = 0
        # the handle's own count (rclpy's wrapper enters the handle at each call); the handle
        # outlives the loop that publishes, as DirectPublisher's does
        self._ask = pub.handle.get_subscription_count
        self._matched = MatchCount(self._ask)

    def get_subscription_count(self) -> int:
        """The DDS writer's matched readers, this process's own included (asked now: the
        graph checks compare it with the graph)."""
        return int(self._ask())

    def wanted(self) -> bool:
        """True while an endpoint of this process takes the topic (a subscriber or an
        observer on the bus) or a DDS reader is matched, as :meth:`remote` knows it: a writer
        of an optional topic (the plant's truth) publishes only then (the plant asks per
        sample and stream)."""
        t = self.writer.topic
        return bool(t.handlers or t.inboxes or t.observers) or self._matched() > 0

    def remote(self) -> bool:
        """True while a reader outside this process is matched."""
        return self.writer.remote(self._matched())

    def publish(self, data: bytes) -> None:
        """Hand ``data`` (serialized) to the in-process subscribers, and to DDS when a remote
        reader is matched or the writer keeps a history."""
        writer = self.writer
        writer.publish(data)
        if self._matched() > writer.topic.readers:  # remote(), inline: ~10 publications a step
            if self.held:  # the first remote reader: the history it would have had first
                for old in self.held.release():
                    self.pub.publish(old)
                    self.on_dds += 1
            self.pub.publish(data)
            self.on_dds += 1
        elif self.held is not None:
            self.held.hold(data)

    def publish_later(self, encode: Callable[[int, Any], bytes], ns: int, value: Any) -> None:
        """Publish ``encode(ns, value)`` (:meth:`DirectPublisher.publish_later`'s form)."""
        self.publish(encode(ns, value))


class DirectPublisher(_Wrapped):
    """A per-sample publisher of one process per node: rclpy's publisher, whose
    :meth:`publish` calls its handle's ``publish_raw`` (rclpy's ``Publisher.publish`` enters the
    handle and checks the type at every call: 1.7 us, the bound method 0.6 us). Serialized
    messages only. The handle lives as long as the node: the hot loop ends before the node is
    destroyed (:func:`.runtime.run`); a publication after that raises rclpy's error.

    With a ``lane`` writer (:mod:`.hostlane`), each message goes into the lanes of this host's
    readers first, and on DDS only while DDS matched more readers than there are lanes
    (:meth:`~dcsms_ros.protocols.lanes.LaneTable.dds`; the count at most
    :data:`~dcsms_ros.protocols.matched.LANE_MATCH_REFRESH_NS` old, a lane's leaving acted on
    at once).

    Parameters
    ----------
    pub : Publisher
        The node's publisher of the topic.
    lane : LaneWriter, optional
        The topic's lanes (None: DDS only).
    """

    def __init__(self, pub: Publisher, lane: LaneWriter | None = None) -> None:
        self.pub = pub
        self.lane = lane
        #: Messages published on DDS (with lanes: those for readers without one).
        self.on_dds = 0
        #: Of those, the ones published after a lane's reader went (its DDS reader is matched
        #: until its process leaves DDS: a node still answering while the plant closes).
        self.on_dds_after_leave = 0
        self._raw: Callable[[bytes], None] = pub.handle.publish_raw
        self._ask: Callable[[], int] = pub.handle.get_subscription_count
        self._matched = MatchCount(self._ask, refresh_ns=LANE_MATCH_REFRESH_NS)
        self._durable = pub.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
        # with lanes: whether every message goes on DDS too, and until when that holds
        self._on_dds = False
        self._route_due = -1
        self._route_left = 0
        self._observer: Callable[[bytes | Deferred, int], None] | None = None
        #: whether :meth:`observe` added an observer
        self.observed = False

    def publish(self, data: bytes) -> None:
        """Publish ``data`` (serialized) on DDS, then hand it to the observer, if any. With
        an observer, a volatile writer skips DDS while no reader is matched (the plant's truth
        topics, recorded in the process: no reader of them elsewhere; the count is at most
        :data:`~dcsms_ros.protocols.matched.LANE_MATCH_REFRESH_NS` old); a transient-local
        one always publishes, for the history a late reader gets."""
        obs = self._observer
        lane = self.lane
        if lane is not None:
            now_ns = time.monotonic_ns()
            if now_ns >= self._route_due or lane.left != self._route_left:
                self._route(lane, now_ns)  # first: a reader found now gets this message too
            t_ns = time.time_ns()
            # on DDS too: too long for a lane, or a DDS reader without one
            if not lane.write(data, t_ns) or self._on_dds:
                self._raw(data)
                self.on_dds += 1
                if lane.left:
                    self.on_dds_after_leave += 1
            if obs is not None:
                obs(data, t_ns)
            return
        if obs is None:
            self._raw(data)
            return
        if self._durable or self._matched():
            self._raw(data)
        obs(data, time.time_ns())


    def publish_later(self, encode: Callable[[int, Any], bytes], ns: int, value: Any) -> None:
        """Publish ``encode(ns, value)``. While the observer alone takes the topic's messages
        (no lane reader and no DDS reader; the plant's true twists, recorded in its process),
        it gets the work instead of the bytes, :data:`Deferred`, and encodes in its batch: one
        warm pass, not one cold call a sample (a woken thread pays several times the
        back-to-back price, ``bench/relay_floor.py --answer``)."""
        obs, lane = self._observer, self.lane
        if obs is not None and lane is not None:
            now_ns = time.monotonic_ns()
            if now_ns >= self._route_due or lane.left != self._route_left:
                self._route(lane, now_ns)
            if not lane.lanes and not self._on_dds:
                obs((encode, ns, value), time.time_ns())
                return
        self.publish(encode(ns, value))

    def _route(self, lane: LaneWriter, now_ns: int) -> None:
        """Judge whether the messages go on DDS too (:meth:`.LaneWriter.dds`), for the next
        :data:`~dcsms_ros.protocols.matched.LANE_MATCH_REFRESH_NS` or until a lane closes: the DDS
        count is asked that often anyway, and judged once per message the decision cost a
        process per node ~4 Python calls a message (5 messages a sample in the plant)."""
        self._on_dds = lane.dds(int(self._ask()), now_ns, 0)
        self._route_due = now_ns + LANE_MATCH_REFRESH_NS
        self._route_left = lane.left

    def observe(self, observer: Callable[[bytes | Deferred, int], None]) -> None:
        """After each publication, call ``observer(data, t_ns)``: the bytes (or, from
        :meth:`publish_later`, the :data:`Deferred` work that makes them) and the system
        time (ns) of the publication. Used by the recorder of the node's own process
        (``dcsms up --record``, one process per node): it writes every message as published,
        without a DDS reader. Call before the hot loop starts."""
        self._observer = observer
        self.observed = True

    def wanted(self) -> bool:
        """True while a DDS reader is matched or an observer takes every message."""
        return self.observed or self.get_subscription_count() > 0


#: What a node's per-sample publisher is: a :class:`BusPublisher` composed, else a
#: :class:`DirectPublisher` (or rclpy's own).
SamplePublisher = Publisher | BusPublisher | DirectPublisher
#: A per-sample publisher made by a node's hot path.
HotPublisher = BusPublisher | DirectPublisher

__all__ = ["BusPublisher", "Deferred", "DirectPublisher", "HotPublisher", "SamplePublisher"]
