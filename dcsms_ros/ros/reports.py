"""A node's ``/diagnostics`` reports, built and published outside its hot-path lock.

A node reads its counters under the lock (every callback runs under it: :mod:`.serialized`)
and hands them to :meth:`Reports.publish` as plain values. Building the DiagnosticArray and
publishing it costs ~0.2-1 ms of Python, and in the executor's thread, which runs under the
normal scheduler, another process may preempt it for milliseconds; under the lock, the
SCHED_FIFO hot thread waited that long (controllers: 3.5-35 ms longest holds per 20 s run).
So the building and the publication go through the hot path's ``later.after``
(:mod:`dcsms_ros.protocols.afterlock`). A report read earlier than one already published
(the hot loop reports at once, the executor's report waits for the lock's release) is
dropped: readers see the counters in the order they were read. The array is serialised in
Python and published with the GIL released (:mod:`.gilfree`): built by rclpy and published as
an object, it held the GIL for ~0.4 ms a report and kept a real-time thread of the process
waiting.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.publisher import Publisher

from dcsms_ros.cdr import encode_diagnostics
from dcsms_ros.core import topics
from dcsms_ros.core.topics import status_name
from dcsms_ros.ros import qos
from dcsms_ros.ros.gilfree import publish_bytes
from dcsms_ros.ros.hotpath import HotPath

#: hardware_id of every status
HARDWARE_ID = "dcsms"


class Status(NamedTuple):
    """One DiagnosticStatus of a report, as plain values read under the lock."""

    level: bytes
    message: str
    values: Mapping[str, object]
    #: part of the node (``dcsms/plant_simulator/<sub>``), "" for the node itself
    sub: str = ""


class Reports:
    """The ``/diagnostics`` publisher of a node with a hot path.

    Parameters
    ----------
    node : Node
        The reporting node (its full name names the statuses).
    hot : HotPath
        Its hot path (its ``later.after`` defers the publication).
    """

    def __init__(self, node: Node, hot: HotPath) -> None:
        self.node, self.hot = node, hot
        self.pub: Publisher = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS,
                                                    qos.status())
        self._read = 0  # reports read (under the hot lock)
        self._sent = 0  # the newest one published
        self._order = threading.Lock()  # the executor's thread and the hot thread publish

    def publish(self, stamp_ns: int, statuses: Sequence[Status]) -> None:
        """Publish a report of ``statuses`` stamped ``stamp_ns`` (ns), once the callback in
        progress released the lock. Call under the hot lock (as every node callback runs)."""
        self._read += 1
        seq = self._read
        self.hot.later.after(lambda: self._send(seq, stamp_ns, statuses))

    def _send(self, seq: int, stamp_ns: int, statuses: Sequence[Status]) -> None:
        # named after the node's full name (dcsms/plant_simulator, and .../<sub> for a part),
        # as /diagnostics tools group them
        fqn = self.node.get_fully_qualified_name()
        data = encode_diagnostics(max(stamp_ns, 0), [
            (s.level[0], status_name(fqn, s.sub), s.message, HARDWARE_ID, s.values)
            for s in statuses])
        with self._order:
            if seq < self._sent:
                return  # a newer report went out while this one waited for the lock
            self._sent = seq
            publish_bytes(self.pub, data)


__all__ = ["HARDWARE_ID", "Reports", "Status"]
