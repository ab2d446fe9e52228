"""One hot-path subscription's lane (:mod:`.hostlane`) beside its DDS reader.

The subscription's messages come from the lane while every DDS writer it matched serves it
there (:meth:`~dcsms_ros.protocols.lanes.LaneSource.covered`); its DDS reader then holds only
the copies a lane writer publishes for readers without a lane, and is left unread. Otherwise
(a writer without a lane: another host, a tool, a transient-local writer) DDS is read too, and
each message cancels its copy the other way (:class:`~dcsms_ros.protocols.lanes.CopyLedger`).
:class:`~.hotpath.HotPath` keeps one per subscription of a process of one node; its hot loop
waits on the lanes' FIFOs while each of them is covered (:meth:`LaneInput.state`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.subscription import Subscription

from dcsms_ros.protocols.lanes import CopyLedger
from dcsms_ros.protocols.matched import LANE_MATCH_REFRESH_NS, MatchCount
from dcsms_ros.ros import hostlane
from dcsms_ros.ros.connectivity import UNKNOWN_NODE
from dcsms_ros.ros.hostlane import LaneReader, LaneWriter

#: How long (s) a reader waits, after its DDS reader matched a writer, for that writer's hello on
#: the lane before it counts the writer as one without a lane (another host, a tool): the
#: real-time start-up waits that long for such a writer.
HELLO_WAIT_S = 0.3

#: How often (s) a lane no writer serves is looked at for a new writer's hello: the hot loop
#: waits on DDS at most that long then (:mod:`.hotloop`), and a lane input reads its FIFO at
#: most that often (a read that finds nothing costs a system call).
PROBE_S = 0.01

#: How long (s) a lane input's state (:meth:`LaneInput.state`) is kept while no writer says
#: hello or bye: the DDS matched-writer count it compares with is that old anyway
#: (:data:`~dcsms_ros.protocols.matched.LANE_MATCH_REFRESH_NS`). Judging it at every wake-up,
#: twice, cost a controller 3-5 % of its CPU per sample (same-run A/B: docs/performance.md, "A
#: lane input's state once a millisecond").
STATE_S = LANE_MATCH_REFRESH_NS * 1e-9

#: :meth:`LaneInput.state`: every DDS writer serves the lane.
LANES = "lanes"
#: Some writers serve the lane, some only DDS.
MIXED = "mixed"
#: No writer serves the lane (yet).
DDS = "dds"


class LaneInput:
    """The lane of subscription ``sub`` (raw: serialized messages).

    Parameters
    ----------
    sub : Subscription
        The DDS reader of the same topic (its matched-writer count is asked at most every
        :data:`STATE_S`).
    reader : LaneReader
        Its lane.
    """

    def __init__(self, sub: Subscription, reader: LaneReader) -> None:
        self.sub = sub
        self.reader = reader
        self.fd = self.reader.fd
        self._dds = MatchCount(sub.handle.get_publisher_count, refresh_ns=LANE_MATCH_REFRESH_NS)
        self._from_lane, self._from_dds = CopyLedger(), CopyLedger()
        self._pending: list[tuple[bytes, int]] = []
        self._matched_at: float | None = None
        self._probe_at = 0.0
        self._state, self._state_until, self._state_version = DDS, -1.0, -1

    def state(self, now: float) -> str:
        """:data:`LANES`, :data:`MIXED` or :data:`DDS` (``now``: monotonic s), judged again
        after :data:`STATE_S` or once a writer said hello or bye."""
        source = self.reader.source
        if now < self._state_until and source.version == self._state_version:
            return self._state
        version = source.version
        writers = self.reader.writers(now)
        state = DDS if not writers else LANES if writers >= self._dds() else MIXED
        self._state, self._state_until, self._state_version = state, now + STATE_S, version
        return state

    @property
    def pending(self) -> bool:
        """True if :meth:`poll` holds messages not delivered yet."""
        return bool(self._pending)

    def poll(self) -> None:
        """Read what the lane holds into this input (hellos included) without delivering it:
        the readiness check learns of new lane writers before the hot loop reads."""
        self._pending += self.reader.read()

    def drain(self, handler: Callable[..., None], latest_only: bool = False,
              timed: bool = True) -> int:
        """Deliver what arrived, oldest first: ``handler(data, t_ns)`` (``t_ns``: publication
        on the lane, DDS reception; system clock), ``handler(data)`` if not ``timed``.
        ``latest_only``: only the newest (a keep-last 1 reader). Returns how many."""
        now = time.monotonic()
        if self._pending or self.reader.source.writers or now >= self._probe_at:
            got = self._pending + self.reader.read() if self._pending else self.reader.read()
            self._pending = []
            self._probe_at = now + PROBE_S
        else:  # no lane writer: a new one's hello is looked for every PROBE_S, not each time
            got = []
        if now < self._state_until and self.reader.source.version == self._state_version:
            state = self._state  # state()'s kept answer, without its call at every wake-up
        else:
            state = self.state(now)
        if state == MIXED:
            got = self._mixed(got)
        elif state == DDS:
            got = self._take_dds() + got
        if not got:
            return 0
        if latest_only and len(got) > 1:
            got = got[-1:]
        if timed:
            for data, t in got:
                handler(data, t)
        else:  # no wrapper dropping the time: a call less per message
            for data, _t in got:
                handler(data)
        return len(got)

    def _take_dds(self) -> list[tuple[bytes, int]]:
        """Every message queued on the DDS reader, with its reception time."""
        out: list[tuple[bytes, int]] = []
        h, typ = self.sub.handle, self.sub.msg_type
        with h:
            while True:
                got = h.take_message(typ, True)
                if got is None:
                    break
                out.append((got[0], got[1]["received_timestamp"]))
        return out

    def _mixed(self, lane: list[tuple[bytes, int]]) -> list[tuple[bytes, int]]:
        """DDS and lane messages, each without the copies of what the other way delivered
        (the lane's first: a writer writes its lanes before DDS)."""
        from_lane, from_dds = self._from_lane, self._from_dds
        out = []
        for data, t in lane:
            if not from_dds.cancel(data):
                from_lane.add(data)
                out.append((data, t))
        for data, t in self._take_dds():
            if not from_lane.cancel(data):
                from_dds.add(data)
                out.append((data, t))
        return out

    def ready(self, now: float) -> bool:
        """True once the DDS reader matched a writer and each matched writer said hello, or
        :data:`HELLO_WAIT_S` passed since the first match (a writer without a lane)."""
        if self.sub.get_publisher_count() == 0:
            self._matched_at = None
            return False
        if self._matched_at is None:
            self._matched_at = now
        self.poll()
        return self.state(now) == LANES or now - self._matched_at >= HELLO_WAIT_S

    def close(self) -> None:
        """Remove the lane."""
        self.reader.close()


class PathLanes:
    """The lanes of one hot path (:class:`~.hotpath.HotPath`, one process per node): its
    subscriptions' inputs, served (delivered by :meth:`serve` on the hot loop) or detached
    (drained by their owner), and its per-sample writers' lanes.

    Parameters
    ----------
    node : Node
        The path's node (its name marks its lanes; its graph view tells a writer which
        readers have no lane; its logger says which subscription got none).
    root : Path
        The lanes' directory (:func:`~.hostlane.lane_root` of the node's ROS domain).
    """

    def __init__(self, node: Node, root: Path) -> None:
        self.node, self.root = node, root
        self.inputs: dict[Subscription, LaneInput] = {}
        #: served inputs: input, handler of the data, flush, keep-last 1
        self._served: list[tuple[LaneInput, Callable[[Any], None],
                                 Callable[[], None] | None, bool]] = []
        self.writers: list[LaneWriter] = []

    def reader(self, topic: str) -> LaneReader | None:
        """The FIFO of a subscription to ``topic`` (fully resolved), made before its DDS
        reader, so that no writer matches that reader without finding its lane; None (a
        warning, and the subscription reads DDS alone) if it could not be made."""
        try:
            r = LaneReader(topic, self.root, self.node.get_fully_qualified_name())
        except OSError as exc:  # e.g. a file system without FIFOs
            self.node.get_logger().warning(f"no host lane for {topic} ({exc}): DDS only")
            return None
        if r.refused:
            self.node.get_logger().warning(
                f"host lane for {topic}: a {hostlane.PIPE_SIZE}-byte pipe refused "
                f"({r.refused}: the user's pipe quota or fs.pipe-max-size), {r.capacity} "
                f"bytes: a reader that falls behind loses messages sooner")
        return r

    def serve_input(self, sub: Subscription, reader: LaneReader,
                    handler: Callable[[Any], None], flush: Callable[[], None] | None,
                    latest_only: bool) -> None:
        """``sub``'s lane ``reader``, whose messages :meth:`serve` hands to ``handler(data)``
        (``flush()`` after each round that delivered; ``latest_only``: keep-last 1)."""
        self._served.append((self.detached_input(sub, reader), handler, flush, latest_only))

    def detached_input(self, sub: Subscription, reader: LaneReader) -> LaneInput:
        """``sub``'s lane ``reader``, drained by its owner (:meth:`LaneInput.drain`)."""
        lane = self.inputs[sub] = LaneInput(sub, reader)
        return lane

    def writer(self, topic: str) -> LaneWriter:
        """A lane writer of ``topic`` (closed with the path)."""
        nd = self.node
        w = LaneWriter(topic, self.root, lambda: _reader_nodes(nd, topic),
                       lambda: nd.count_subscribers(topic))
        self.writers.append(w)
        return w

    def serve(self) -> int:
        """Deliver what arrived for the served inputs; returns how many."""
        n = 0
        for lane, handler, flush, latest in self._served:
            got = lane.drain(handler, latest, timed=False)
            if got:
                n += got
                if flush is not None:
                    flush()
        return n

    def fds(self) -> list[int]:
        """The FIFOs of the served inputs (the hot loop may wait on them)."""
        return [lane.fd for lane, _, _, _ in self._served]

    def state(self, now: float, served: int) -> str:
        """How the hot loop must wait for the path's ``served`` subscriptions: on their lanes
        only (:data:`LANES`: each has one, served only there), on the lanes and DDS
        (:data:`MIXED`), or on DDS (:data:`DDS`: no lane writer serves any)."""
        if not self._served:
            return DDS
        states = {lane.state(now) for lane, _, _, _ in self._served}
        if states == {LANES} and len(self._served) == served:
            return LANES
        return DDS if states == {DDS} else MIXED

    def pending(self) -> bool:
        """True if a readiness check read messages of a served input off its FIFO (the hot
        loop, waiting on the FIFO, must be woken to deliver them)."""
        return any(lane.pending for lane, _, _, _ in self._served)

    def connect(self) -> dict[Subscription, LaneInput]:
        """Open each writer's lanes to the readers found since the last look; returns the
        inputs."""
        for w in self.writers:
            w.refresh()
        return self.inputs

    def close(self) -> None:
        """Say bye on the writers' lanes and remove the inputs' FIFOs."""
        for w in self.writers:
            w.close()
        for lane in self.inputs.values():
            lane.close()


def lanes_for(node: Node) -> PathLanes | None:
    """The lanes of ``node``'s hot path (one process per node; the lanes' directory of the
    node's ROS domain), or None when lanes are off (:func:`~.hostlane.enabled`) or its
    directory cannot be made (a warning says so)."""
    if not hostlane.enabled():
        return None
    try:
        return PathLanes(node, hostlane.lane_root(node.context.get_domain_id()))
    except OSError as exc:
        node.get_logger().warning(f"host lanes off ({exc}): every per-sample message on DDS")
        return None


def _reader_nodes(node: Node, topic: str) -> tuple[list[str], bool]:
    """The fully qualified node name of each subscription of ``topic`` in ``node``'s graph
    view, and whether every one's node is known (a reader announced before its node shows a
    placeholder name, no lane's)."""
    infos = node.get_subscriptions_info_by_topic(topic)
    return ([f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos],
            all(i.node_name != UNKNOWN_NODE for i in infos))


__all__ = ["DDS", "HELLO_WAIT_S", "LANES", "MIXED", "PROBE_S", "STATE_S", "LaneInput",
           "PathLanes", "lanes_for"]
