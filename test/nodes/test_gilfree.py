"""rcl calls with the GIL released (ros/gilfree.py) against rclpy's own: real nodes, real DDS."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import SetBool

from dcsms_ros import cdr
from dcsms_ros.ros import gilfree


@pytest.fixture
def node(ctx: Context) -> Iterator[Node]:
    n = Node("gilfree_probe", context=ctx)
    yield n
    n.destroy_node()


def _spin_until(ex: SingleThreadedExecutor, done: Callable[[], bool], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not done() and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)


def test_the_library_is_found_beside_rclpy() -> None:
    """The wheels' rclpy loaded librcl; the GIL-free path is the one that runs here."""
    assert gilfree.AVAILABLE


def test_published_bytes_arrive_as_sent(ctx: Context, node: Node) -> None:
    pub = node.create_publisher(String, "gilfree_text", 10)
    got: list[bytes] = []
    node.create_subscription(String, "gilfree_text", got.append, 10, raw=True)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    _spin_until(ex, lambda: pub.get_subscription_count() > 0, 5.0)
    sent = [cdr.encode_string(t) for t in ("", "a", "twelve chars", "é" * 33)]
    for data in sent:
        gilfree.publish_bytes(pub, data)
    _spin_until(ex, lambda: len(got) == len(sent), 5.0)
    assert got == sent
    ex.shutdown()


def test_graph_queries_agree_with_rclpy(ctx: Context, node: Node) -> None:
    other = Node("gilfree_other", context=ctx)
    other.create_publisher(String, "gilfree_a", 10)
    other.create_publisher(String, "gilfree_a", 10)
    node.create_publisher(String, "gilfree_b", 10)
    end = time.monotonic() + 5.0
    while node.count_publishers("/gilfree_a") < 2 and time.monotonic() < end:
        time.sleep(0.05)
    assert sorted(gilfree.topic_names_and_types(node)) == \
        sorted(node.get_topic_names_and_types())
    assert ("/gilfree_a", ["std_msgs/msg/String"]) in gilfree.topic_names_and_types(node)
    for topic, n in (("/gilfree_a", 2), ("/gilfree_b", 1), ("/gilfree_none", 0)):
        assert gilfree.count_publishers(node, topic) == node.count_publishers(topic) == n
    other.destroy_node()


def test_an_rcl_error_is_one_line_naming_the_call(node: Node) -> None:
    with pytest.raises(RuntimeError, match=r"^counting the publishers of bad topic failed "
                                           r"\(\d+\): [^\n]+$"):
        gilfree.count_publishers(node, "bad topic")
    assert gilfree.count_publishers(node, "/fine") == 0  # the error state was reset


def _stamps_inside(call: Callable[[], Any], n: int) -> int:
    """How many times another Python thread, waking every 0.2 ms, ran while this one was
    inside ``call`` (``n`` calls), with a switch interval (1 s) that no call comes near: only
    a call that releases the GIL lets it run Python meanwhile (the composed driver, woken at
    its deadline while the executor's thread is in one)."""
    stamps: list[float] = []
    stop = threading.Event()

    def other() -> None:
        while not stop.is_set():
            time.sleep(2e-4)
            stamps.append(time.monotonic())

    old = sys.getswitchinterval()
    sys.setswitchinterval(1.0)
    t = threading.Thread(target=other)
    spans = []
    try:
        t.start()
        for _ in range(n):
            t0 = time.monotonic()
            call()
            spans.append((t0, time.monotonic()))
    finally:
        stop.set()
        sys.setswitchinterval(old)
        t.join()
    return sum(any(a < s < b for a, b in spans) for s in stamps)


def test_the_long_calls_let_another_python_thread_run(ctx: Context, node: Node) -> None:
    """The point of the module, on calls made long on purpose (300 topics to list, 4 MB to
    publish to a reader): another thread runs Python during them; during rclpy's own, never."""
    for i in range(300):
        node.create_publisher(String, f"gilfree_many_{i}", 1)
    pub = node.create_publisher(String, "gilfree_big", 1)
    node.create_subscription(String, "gilfree_big", lambda m: None, 1, raw=True)
    end = time.monotonic() + 5.0
    while pub.get_subscription_count() < 1 and time.monotonic() < end:
        time.sleep(0.05)
    data = cdr.encode_string("a" * 4_000_000)
    assert _stamps_inside(node.get_topic_names_and_types, 50) == 0
    assert _stamps_inside(lambda: pub.publish(data), 50) == 0
    assert _stamps_inside(lambda: gilfree.topic_names_and_types(node), 50) >= 3
    assert _stamps_inside(lambda: gilfree.publish_bytes(pub, data), 50) >= 3


def test_service_readiness_agrees_with_rclpy(ctx: Context, node: Node) -> None:
    """mode_switch's check of the controllers' enable services: not there, there, gone."""
    client = node.create_client(SetBool, "gilfree_enable")
    assert gilfree.service_is_ready(node, client) is client.service_is_ready() is False
    other = Node("gilfree_server", context=ctx)
    srv = other.create_service(SetBool, "gilfree_enable", lambda q, r: r)
    _wait_for(client.service_is_ready, 5.0)
    assert gilfree.service_is_ready(node, client) is True
    other.destroy_service(srv)
    _wait_for(lambda: not client.service_is_ready(), 5.0)
    assert gilfree.service_is_ready(node, client) is False
    other.destroy_node()


def test_a_destroyed_client_is_refused_as_rclpy_refuses_it(node: Node) -> None:
    client = node.create_client(SetBool, "gilfree_gone")
    node.destroy_client(client)
    with pytest.raises(InvalidHandle):
        client.service_is_ready()
    with pytest.raises(InvalidHandle):
        gilfree.service_is_ready(node, client)


def _wait_for(done: Callable[[], bool], timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not done():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.02)
