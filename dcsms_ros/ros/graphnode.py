"""The rclpy node every node of the package derives from: publishers without event handlers,
and periodic jobs declared for the host (:meth:`GraphNode.housekeeping`).

rclpy gives every publisher two QoS-event handlers by default (incompatible QoS, incompatible
type), each a waitable that the executor adds to its wait set, checks and releases in Python on
every wake-up. A composed graph has ~33 publishers (the nodes' own, plus one for
``/parameter_events`` per node): 66 of the 104 waitables its executor rebuilt 40-45 times a
second. Measured composed, recorded, real time at SCHED_FIFO 50 on a slow day
(docs/performance.md): the executor thread used 22.5-22.7 % of a core without them against
26.8-27.2 % with them, in alternating runs.

Nothing a user sees is lost: an incompatibility is reported on both sides of a match, and the
subscription's side still logs it (rclpy's and rclcpp's subscriptions, ours included, keep their
default handlers), in the process that would miss the messages. A publisher that wants events
passes its own ``event_callbacks``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile
from rclpy.timer import Timer

from dcsms_ros.ros.clock import steady_timer
from dcsms_ros.ros.housekeeping import Job


class GraphNode(Node):
    """An rclpy :class:`~rclpy.node.Node` whose publishers have no default event handlers.

    Attributes
    ----------
    jobs : list of Job
        The periodic jobs declared with :meth:`housekeeping`.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.jobs: list[Job] = []
        super().__init__(*args, **kwargs)

    def housekeeping(self, period_s: float, callback: Callable[[], object],
                     group: CallbackGroup | None = None) -> Timer:
        """A periodic job: ``callback`` every ``period_s`` s of steady time, on a timer of its
        own (in ``group``) until a host adopts it (:class:`.housekeeping.Housekeeper`: one
        timer for the jobs of every node of the process). Returns that timer."""
        timer = steady_timer(self, period_s, callback, group)
        self.jobs.append(Job(self, period_s, timer))
        return timer

    def create_publisher(self, msg_type: Any, topic: str, qos_profile: QoSProfile | int, *,
                         event_callbacks: PublisherEventCallbacks | None = None,
                         **kwargs: Any) -> Publisher:
        """:meth:`rclpy.node.Node.create_publisher`, with no event handlers unless
        ``event_callbacks`` asks for some."""
        if event_callbacks is None:
            event_callbacks = PublisherEventCallbacks(use_default_callbacks=False)
        return super().create_publisher(msg_type, topic, qos_profile,
                                        event_callbacks=event_callbacks, **kwargs)


__all__ = ["GraphNode"]
