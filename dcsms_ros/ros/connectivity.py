"""The graph's connectivity, checked in one place from one node's view of the ROS graph.

Three questions are asked of the graph before and while it runs, by the plant (before sample
0), the supervisor of ``dcsms up`` (before it prints "graph connected"), every lockstep answer
(before the first one goes out) and a controller (before its fade starts):

- Which of the loop's ends is not there yet? (:func:`missing_ends` of :func:`control_path`.)
- Has a writer matched every reader this node sees? (:func:`writer_matched`,
  :func:`publishers_matched`.) ``pub.get_subscription_count()`` is the DDS writer's own
  matched-reader count, so a sample published after this returns True reaches every reader
  known so far; the graph view (``count_subscribers``) can run ahead of the match.
- Does a given node, or any node outside the graph (an observer: recorder, probe), read a
  topic? (:func:`has_reader`, :func:`outside_graph`.)
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass

from rclpy.node import Node

from dcsms_ros.core import topics
from dcsms_ros.core.modes import ControllerId
from dcsms_ros.ros.intraprocess import SamplePublisher

#: Node names of the graph itself; a subscriber from any other node is an observer.
GRAPH_NODES = ("plant_simulator", "sensor_decoupling", "mode_switch", "excitation")
#: The node name rmw shows for an endpoint whose node's entities were not announced yet
#: (rmw_dds_common's graph cache): it may be a node of the graph.
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"


@dataclass(frozen=True)
class End:
    """One end of a topic the graph needs: a publisher (``publisher=True``) or a subscriber of
    ``topic``, provided by ``who`` (the name shown while it is missing)."""

    topic: str
    publisher: bool
    who: str


def control_path(names: topics.Names, controllers: Iterable[str]) -> list[End]:
    """The per-sample loop's ends: each controller's force publisher and the raw sensor
    channels' reader (the decoupling)."""
    return [End(names.force(c), True, c) for c in controllers] + [
        End(names.sensors_raw, False, "sensor_decoupling")]


def missing_ends(node: Node, ends: Iterable[End]) -> list[str]:
    """``who`` of each end no node of ``node``'s graph view provides (each name once, in
    order); empty when all are there."""
    out: list[str] = []
    for e in ends:
        count = node.count_publishers(e.topic) if e.publisher else node.count_subscribers(e.topic)
        if count == 0 and e.who not in out:
            out.append(e.who)
    return out


def in_graph(node_name: str) -> bool:
    """True for a node of the graph itself (a subscriber from any other node is an observer)."""
    return node_name in GRAPH_NODES or ControllerId.is_valid(node_name)


def outside_graph(node: Node, topic: str) -> bool:
    """True if ``topic`` has a subscriber of a known node that is not a node of the graph (an
    observer). A reader is announced before its node's name: seen at a plant's start on the
    recorder's readers, for up to 0.1 s; a graph node's reader may show the same."""
    return any(not in_graph(i.node_name) and i.node_name != UNKNOWN_NODE
               for i in node.get_subscriptions_info_by_topic(topic))


def has_reader(node: Node, topic: str, reader: str) -> bool:
    """True if the node named ``reader`` subscribes to ``topic`` (in ``node``'s graph view)."""
    return any(i.node_name == reader for i in node.get_subscriptions_info_by_topic(topic))


def writer_matched(node: Node, pub: SamplePublisher) -> bool:
    """True when ``pub``'s DDS writer has matched every reader of its topic ``node`` sees."""
    return pub.get_subscription_count() >= node.count_subscribers(pub.topic_name)


def unmatched_publishers(node: Node, pubs: Iterable[SamplePublisher],
                         observed: Collection[str]) -> list[str]:
    """What keeps ``pubs`` from :func:`publishers_matched`: the topic of each publisher that
    has not matched every reader this node's graph view shows, ``observer of <topic>`` for an
    observed topic among them without a reader outside the graph."""
    out: list[str] = []
    for pub in pubs:
        if not writer_matched(node, pub):
            out.append(pub.topic_name)
        elif pub.topic_name in observed and not outside_graph(node, pub.topic_name):
            out.append(f"observer of {pub.topic_name}")
    return out


def publishers_matched(node: Node, pubs: Sequence[SamplePublisher],
                       observed: Collection[str]) -> bool:
    """True when each publisher has matched every reader this node's graph view shows, and
    each observed topic among them has a reader outside the graph."""
    return not unmatched_publishers(node, pubs, observed)


__all__ = ["GRAPH_NODES", "UNKNOWN_NODE", "End", "control_path", "has_reader", "in_graph",
           "missing_ends", "outside_graph", "publishers_matched", "unmatched_publishers",
           "writer_matched"]
