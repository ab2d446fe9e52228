"""Real-time start-up confirmed from both sides of every DDS match (ros/readiness.py): a node
of the control path announces its role once its readers matched a writer, and the plant does
not publish sample 0 before it heard the decoupling and every controller."""

from __future__ import annotations

import time

import pytest
import rclpy
from geometry_msgs.msg import TwistStamped, WrenchStamped
from node_helpers import executor_for, overrides, realtime_plant, spin_until
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool

from dcsms_ros.core import topics
from dcsms_ros.nodes.feedback_controller import FeedbackControllerNode
from dcsms_ros.nodes.sensor_decoupling import SensorDecouplingNode
from dcsms_ros.ros import qos
from dcsms_ros.ros.readiness import DECOUPLING, ReadySet

#: How long the plant is watched for a start it must not make (its handshake otherwise needs
#: its writers' matches and 0.2 s more: well inside this).
QUIET_S = 2.0


def test_the_plant_waits_for_every_announcement_before_sample_0(ctx, cfg):
    """A probe provides every end the plant's graph view asks for (a raw reader, fb_stage1's
    force writer) but announces nothing: no sample for 2 s (before, the plant started on its
    writers' match, ~0.3 s here). Announcing the decoupling alone is not enough; with
    fb_stage1 announced too the plant steps."""
    plant, probe, raw = realtime_plant(ctx, cfg, "ready_probe", 60.0, deep=True)
    force = probe.create_publisher(WrenchStamped, topics.force_topic("fb_stage1"),
                                   qos.stream_pub(False))
    ready = probe.create_publisher(Bool, topics.DEFAULT.ready(DECOUPLING), qos.latched())
    ready_fb = probe.create_publisher(Bool, topics.DEFAULT.ready("fb_stage1"), qos.latched())
    ex = executor_for(ctx, plant, probe)
    try:
        assert spin_until(ex, lambda: force.get_subscription_count() > 0
                          and plant.hot.unmatched() == [], 10.0), "the probe never matched"
        assert not spin_until(ex, lambda: bool(raw), QUIET_S), "started unannounced"
        ready.publish(Bool(data=True))
        assert not spin_until(ex, lambda: bool(raw), QUIET_S), "started without fb_stage1"
        t0 = time.monotonic()
        ready_fb.publish(Bool(data=True))
        assert spin_until(ex, lambda: bool(raw), 10.0), "never started"
        print(f"first sample {time.monotonic() - t0:.3f} s after the last announcement")
        assert raw[0] == 0  # sample 0 is the first one out
    finally:
        plant.hot.stop()
        ex.shutdown()
        for n in (plant, probe):
            n.destroy_node()


@pytest.mark.parametrize("role", [DECOUPLING, "fb_stage1"])
def test_a_node_announces_once_its_reader_matched_a_writer(ctx, cfg, role):
    """The real decoupling (fb_stage1) is silent while nothing publishes its input, and
    announces its role, once, soon after a writer of raw channels (stage-1 velocity) appears."""
    params = overrides(cfg, schedule="realtime")
    if role == DECOUPLING:
        node = SensorDecouplingNode(context=ctx, parameter_overrides=params)
        msg_type, topic = JointState, topics.SENSORS_RAW
    else:
        node = FeedbackControllerNode(context=ctx, parameter_overrides=[
            *params, Parameter("force_reader", value="")])
        msg_type, topic = TwistStamped, topics.velocity_topic("stage1")
    listener = rclpy.create_node("ready_listener", namespace=topics.NAMESPACE, context=ctx)
    ready = ReadySet(listener, [role])
    ex = executor_for(ctx, node, listener)
    try:
        assert not spin_until(ex, lambda: role in ready.roles, QUIET_S), "announced unmatched"
        assert node.ready is not None and not node.ready.announced
        assert topic in node.ready.missing()
        writer = listener.create_publisher(msg_type, topic, qos.stream_pub(False))
        t0 = time.monotonic()
        assert spin_until(ex, lambda: role in ready.roles, 10.0), "never announced"
        print(f"{role}: announced {time.monotonic() - t0:.3f} s after its input's writer came")
        assert node.ready.announced and node.ready.missing() == []
        assert writer.get_subscription_count() >= 1
    finally:
        node.hot.stop()
        ex.shutdown()
        node.destroy_node()
        listener.destroy_node()


def test_an_observed_topic_holds_the_announcement_until_its_writer_matched_the_observer(ctx, cfg):
    """With stage-1 velocity in ``wait_for_subscribers`` the decoupling, its input matched,
    does not announce while no reader outside the graph exists; once one subscribes, it
    announces only after its velocity writer matched that reader (a writer with host lanes
    sends on DDS only to readers it matched: an outside reader the plant alone waited for got
    samples from ~1.6 s of a 3 s run)."""
    velocity = topics.velocity_topic("stage1")
    node = SensorDecouplingNode(context=ctx, parameter_overrides=[
        *overrides(cfg, schedule="realtime"), Parameter("wait_for_subscribers", value=[velocity])])
    listener = rclpy.create_node("ready_listener", namespace=topics.NAMESPACE, context=ctx)
    ready = ReadySet(listener, [DECOUPLING])
    listener.create_publisher(JointState, topics.SENSORS_RAW, qos.stream_pub(False))
    ex = executor_for(ctx, node, listener)
    observer = None
    try:
        assert node.ready is not None
        assert spin_until(ex, lambda: node.hot.unmatched() == [], 10.0), "input never matched"
        assert not spin_until(ex, lambda: DECOUPLING in ready.roles, QUIET_S), \
            "announced without an observer"
        assert node.ready.missing() == [f"observer of {velocity}"]
        observer = rclpy.create_node("velocity_probe", context=ctx)
        observer.create_subscription(TwistStamped, velocity, lambda m: None,
                                     qos.stream_pub(False))
        ex.add_node(observer)
        assert spin_until(ex, lambda: DECOUPLING in ready.roles, 10.0), "never announced"
        writer = next(p for p in node.hot.writers if p.topic_name == velocity)
        assert writer.get_subscription_count() >= 1
        assert node.ready.missing() == []
    finally:
        node.hot.stop()
        ex.shutdown()
        for n in (node, listener, observer):
            if n is not None:
                n.destroy_node()
