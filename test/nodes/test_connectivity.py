"""The one graph-connectivity check (ros/connectivity.py) and the one steady clock
(ros/clock.py), against real nodes over DDS."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
from geometry_msgs.msg import WrenchStamped
from rclpy.clock import ClockType
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.topic_endpoint_info import TopicEndpointInfo
from sensor_msgs.msg import JointState

from dcsms_ros.core import topics
from dcsms_ros.ros import qos
from dcsms_ros.ros.clock import STEADY, steady_timer
from dcsms_ros.ros.connectivity import (
    UNKNOWN_NODE,
    End,
    control_path,
    has_reader,
    missing_ends,
    outside_graph,
    publishers_matched,
    writer_matched,
)


def _until(executor: SingleThreadedExecutor, cond: Callable[[], bool], timeout_s: float = 10.0
           ) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        executor.spin_once(timeout_sec=0.02)
    return cond()


def test_missing_ends_name_each_absent_node_until_it_comes(ctx: Context) -> None:
    """The loop's ends are missing, by the name of their node, until a node provides them;
    a name is listed once even if it lacks several ends."""
    names = topics.Names("/t_conn")
    probe = Node("conn_probe", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(probe)
    others: list[Node] = []
    try:
        ends = [*control_path(names, ["fb_stage1", "ff_stage1"]),
                End(names.trip_check, False, "mode_switch"),
                End(names.trip_checked, True, "mode_switch")]
        assert missing_ends(probe, ends) == ["fb_stage1", "ff_stage1", "sensor_decoupling",
                                             "mode_switch"]
        fb = Node("fb_stage1", namespace="/t_conn", context=ctx)
        dec = Node("sensor_decoupling", namespace="/t_conn", context=ctx)
        others += [fb, dec]
        fb.create_publisher(WrenchStamped, names.force("fb_stage1"), qos.stream_pub(True))
        dec.create_subscription(JointState, names.sensors_raw, lambda m: None,
                                qos.stream_sub(True))
        assert _until(executor, lambda: missing_ends(probe, ends) == ["ff_stage1",
                                                                      "mode_switch"])
        assert has_reader(probe, names.sensors_raw, "sensor_decoupling")
        assert not has_reader(probe, names.sensors_raw, "dcsms_recorder")
    finally:
        executor.shutdown()
        for n in [probe, *others]:
            n.destroy_node()


def test_a_writer_is_matched_once_every_reader_is_and_an_observer_is_outside(ctx: Context
                                                                             ) -> None:
    """``writer_matched`` follows the DDS writer's matched readers; an observed topic also
    needs a reader that is not a node of the graph (the recorder, a probe)."""
    topic = "/t_conn2/velocity/stage1"
    plant = Node("plant_simulator", namespace="/t_conn2", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(plant)
    others: list[Node] = []
    try:
        pub = plant.create_publisher(WrenchStamped, topic, qos.stream_pub(True))
        assert writer_matched(plant, pub)  # nobody to match yet
        ms = Node("mode_switch", namespace="/t_conn2", context=ctx)
        others.append(ms)
        ms.create_subscription(WrenchStamped, topic, lambda m: None, qos.stream_sub(True))
        assert _until(executor, lambda: plant.count_subscribers(topic) == 1)
        assert _until(executor, lambda: writer_matched(plant, pub))
        assert pub.get_subscription_count() == 1
        assert publishers_matched(plant, [pub], [])
        assert not outside_graph(plant, topic)
        assert not publishers_matched(plant, [pub], [topic])  # no observer yet
        rec = Node("dcsms_recorder", context=ctx)
        others.append(rec)
        rec.create_subscription(WrenchStamped, topic, lambda m: None, qos.stream_sub(True))
        assert _until(executor, lambda: publishers_matched(plant, [pub], [topic]))
        assert outside_graph(plant, topic) and pub.get_subscription_count() == 2
    finally:
        executor.shutdown()
        for n in [plant, *others]:
            n.destroy_node()


class _GraphView:
    """The one graph query ``outside_graph`` makes, answered with rmw's own endpoint infos:
    a reader whose node is not announced yet cannot be made to order over DDS."""

    def __init__(self, infos: list[TopicEndpointInfo]) -> None:
        self.infos = infos

    def get_subscriptions_info_by_topic(self, topic: str) -> list[TopicEndpointInfo]:
        return self.infos


@pytest.mark.parametrize(("names", "outside"), [
    ([UNKNOWN_NODE], False),
    (["mode_switch", UNKNOWN_NODE], False),
    ([UNKNOWN_NODE, "dcsms_recorder"], True),
    (["fb_stage1"], False),
])
def test_a_reader_of_an_unknown_node_is_no_observer(names: list[str], outside: bool) -> None:
    """Until rmw knows a reader's node, the reader may be the graph's own: a plant must not
    start for it (the soak's recorder missed the first 38-864 samples of a topic another
    reader had satisfied)."""
    view = _GraphView([TopicEndpointInfo(node_name=n, node_namespace="/") for n in names])
    assert outside_graph(view, "/t/actuators/applied") is outside  # type: ignore[arg-type]


def test_steady_timer_runs_without_clock_under_sim_time(ctx: Context) -> None:
    """A housekeeping timer on the one steady clock fires although the node is on simulated
    time and nobody publishes ``/clock``; a timer on the node's own clock does not."""
    node = Node("steady_probe", context=ctx,
                parameter_overrides=[Parameter("use_sim_time", value=True)])
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    fired = {"steady": 0, "ros": 0}
    try:
        timer = steady_timer(node, 0.01, lambda: fired.__setitem__("steady", fired["steady"] + 1))
        node.create_timer(0.01, lambda: fired.__setitem__("ros", fired["ros"] + 1))
        assert timer.clock is STEADY and STEADY.clock_type == ClockType.STEADY_TIME
        assert _until(executor, lambda: fired["steady"] >= 5, timeout_s=5.0)
        assert fired["ros"] == 0
    finally:
        executor.shutdown()
        node.destroy_node()
