"""Real-time start-up: the control path's nodes say when DDS matched their ends, the plant
starts once it heard each of them.

A DDS writer and a reader match each other independently. The plant's handshake sees its own
writers' matches (:func:`.connectivity.publishers_matched`), but a reader drops every sample of
a writer it has not matched yet: in one per-process run the plant started on its writer's
match while the decoupling's reader matched 1.44 s later, and the loop ran open that long
(docs/performance.md, fourteenth session). In lockstep that costs nothing (the plant
retransmits sample 0 until every controller answered it); in real time the samples are gone.

So in real time each node of the control path (the decoupling, every controller, the
excitation) runs a :class:`ReadyAnnouncer`: once each of its per-sample readers matched a
writer and each of its per-sample writers matched every reader the node sees, it publishes
True, once, on ``<role>/ready`` (std_msgs/Bool, reliable, transient local: a plant that comes
later still hears it; one writer per topic, as a recorder's sequence check expects). A writer
of a topic in ``wait_for_subscribers`` also waits until its node sees a reader outside the graph
and the writer matched it: the plant's view of that observer says nothing of the writer's
match, and a writer with host lanes sends on DDS only to readers it matched, so an outside
reader of the decoupling's velocity got samples only from ~1.6 s of a 3 s run in 3 of 21 runs
(``test_lanes_graph.py``; docs/performance.md, thirty-seventh session). The
plant's :class:`ReadySet` listens to the roles it needs; its handshake waits for the
decoupling and every controller, bounded by ``handshake_timeout_s`` like the rest.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import partial

from rclpy.node import Node
from std_msgs.msg import Bool

from dcsms_ros.core import topics
from dcsms_ros.ros import qos
from dcsms_ros.ros.clock import steady_timer
from dcsms_ros.ros.connectivity import unmatched_publishers
from dcsms_ros.ros.hotpath import HotPath

#: Seconds between two checks of a node's matches until it announced.
CHECK_S = 0.02
#: The role the sensor-decoupling node announces (whatever its node name).
DECOUPLING = "sensor_decoupling"


class ReadyAnnouncer:
    """Publish True on ``<role>/ready`` once ``hot``'s ends are matched (then stop checking).

    Parameters
    ----------
    node : Node
        The node of ``hot`` (its graph view counts the readers its writers must match).
    hot : HotPath
        The per-sample readers and writers to check.
    role : str
        What the plant waits for: :data:`DECOUPLING`, a controller id or ``excitation``.
    observed : iterable of str
        The node's ``wait_for_subscribers``: topics whose writer waits for an outside reader.
    """

    def __init__(self, node: Node, hot: HotPath, role: str, observed: Iterable[str] = ()
                 ) -> None:
        self.node, self.hot, self.role = node, hot, role
        self.observed = frozenset(observed)
        self.announced = False
        self.pub = node.create_publisher(Bool, topics.LOCAL.ready(role), qos.latched())
        self._timer = steady_timer(node, CHECK_S, self.check)

    def missing(self) -> list[str]:
        """The ends not matched yet: topics of readers without a writer, of writers that have
        not matched every reader the node sees, ``observer of <topic>`` for an observed topic
        the node sees no outside reader of."""
        return self.hot.unmatched() + unmatched_publishers(self.node, self.hot.writers,
                                                           self.observed)

    def check(self) -> bool:
        """Announce if every end is matched; True once announced."""
        if not self.announced and not self.missing():
            self.pub.publish(Bool(data=True))
            self.announced = True
            self._timer.cancel()
        return self.announced


class ReadySet:
    """Which of ``roles`` announced on ``<role>/ready``, as the plant hears them.

    Parameters
    ----------
    node : Node
        The node whose executor delivers the announcements.
    roles : iterable of str
        The roles to wait for.
    """

    def __init__(self, node: Node, roles: Iterable[str]) -> None:
        self.wanted = list(roles)
        self.roles: set[str] = set()
        self.subs = [node.create_subscription(Bool, topics.LOCAL.ready(r), partial(self._on, r),
                                              qos.latched()) for r in self.wanted]

    def _on(self, role: str, msg: Bool) -> None:
        if msg.data:
            self.roles.add(role)

    def missing(self) -> list[str]:
        """The roles not announced yet, in order."""
        return [r for r in self.wanted if r not in self.roles]


__all__ = ["CHECK_S", "DECOUPLING", "ReadyAnnouncer", "ReadySet"]
