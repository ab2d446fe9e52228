"""A hot path's detached readers: subscriptions nobody serves per sample, emptied by their
node when it wants (the plant drains its force readers at each tick; mode_switch's trip
observers take their streams in batches). A reader is served, in this order, by its lane
(one process per node), by the process's in-process bus when its topic has a writer there
(composed), or by its DDS reader. :class:`~.hotpath.HotPath` is the one class that uses this."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription

from dcsms_ros.protocols.localbus import Endpoint, Inbox, LocalBus
from dcsms_ros.ros.hostlane import LaneReader
from dcsms_ros.ros.laneinput import PathLanes


class DetachedReaders:
    """Detached readers of a :class:`~.hotpath.HotPath` (a base class: it uses the path's
    readers, lanes, bus and DDS readers, declared below)."""

    readers: list[Subscription]
    lanes: PathLanes | None
    bus: LocalBus | None
    _inboxes: dict[Subscription, Inbox]
    _replaced: dict[Subscription, Subscription]

    _lane_reader: Callable[[str, bool], LaneReader | None]
    _reader: Callable[[Any, str, Callable[[Any], None], QoSProfile, bool], Subscription]
    _local: Callable[[str, Callable[[bytes], None] | None], Endpoint]
    served_from_dds: Callable[[Subscription], bool]

    def detached(self, msg_type: Any, topic: str, qos: QoSProfile,
                 raw: bool = False) -> Subscription:
        """A subscription nobody waits on; empty it with :meth:`take` or :meth:`drain_timed`."""
        lane = self._lane_reader(topic, raw)
        sub = self._reader(msg_type, topic, lambda m: None, qos, raw)
        self.readers.append(sub)
        if self.bus is not None and raw:
            box = self._local(sub.topic_name, None)
            assert isinstance(box, Inbox)
            self._inboxes[sub] = box
        if self.lanes is not None and lane is not None:
            self.lanes.detached_input(sub, lane)
        return sub

    def take(self, sub: Subscription, limit: int = 100000) -> list[Any]:
        """Every queued message of detached ``sub`` (at most ``limit``), oldest first, taken
        off its queue."""
        if sub not in self._replaced:
            box = self._inboxes.get(sub)
            if box is not None and not self.served_from_dds(sub):
                return box.take(limit)
        out: list[Any] = []
        self.drain_timed(sub, lambda data, _: out.append(data), limit)
        return out

    def drainer(self, sub: Subscription) -> Callable[[Callable[[Any, int], None]], int]:
        """:meth:`drain_timed` of detached ``sub`` as one callable, ``drain(handler)``: its
        lane input's own when it has a lane (the plant drains three forces a sample: a call
        less each)."""
        lane = self.lanes.inputs.get(sub) if self.lanes is not None else None
        if lane is not None:
            return lane.drain
        return partial(self.drain_timed, sub)

    def drain_timed(self, sub: Subscription, handler: Callable[[Any, int], None],
                    limit: int = 100000) -> int:
        """Take every queued message of detached ``sub`` (at most ``limit``), oldest first,
        with its arrival: ``handler(msg, t_ns)`` (system clock, ns: DDS reception, or
        in-process publication)."""
        lane = self.lanes.inputs.get(sub) if self.lanes is not None else None
        if lane is not None:
            return lane.drain(handler)
        if sub in self._replaced:  # no in-process writer: its DDS reader with the QoS asked
            sub = self._replaced[sub]
        else:
            box = self._inboxes.get(sub)
            if box is not None and not self.served_from_dds(sub):
                return box.drain(handler, limit)
        n = 0
        h, typ, raw = sub.handle, sub.msg_type, sub.raw
        with h:
            while n < limit:
                got = h.take_message(typ, raw)
                if got is None:
                    break
                handler(got[0], got[1]["received_timestamp"])
                n += 1
        return n


__all__ = ["DetachedReaders"]
