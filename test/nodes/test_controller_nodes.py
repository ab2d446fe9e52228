"""Controller and decoupling nodes in-process: one step per stamp, cache, NaN guard, enable."""

from __future__ import annotations

import numpy as np
import rclpy
from geometry_msgs.msg import TwistStamped, WrenchStamped
from node_helpers import executor_for, overrides, spin_until
from rosmsgs import joint_state, stamp_ns, twist_array, twist_msg, wrench_array
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from dcsms_ros.core import topics
from dcsms_ros.core.controllers import make_controller
from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.nodes.feedback_controller import FeedbackControllerNode
from dcsms_ros.nodes.sensor_decoupling import SensorDecouplingNode
from dcsms_ros.ros import qos


def _probe(ctx, msg_type, topic, lockstep=True):
    node = rclpy.create_node("probe", context=ctx)
    got = []
    node.create_subscription(msg_type, topic, got.append, qos.stream_pub(lockstep))
    return node, got


def test_feedback_node_steps_once_per_stamp_and_guards_nan(ctx, cfg):
    """One loop step per stamp, a repeated stamp answered from cache, NaN input gives zero."""
    fb = FeedbackControllerNode(context=ctx, parameter_overrides=overrides(
        cfg, schedule="lockstep", stage=1, enabled=True))
    probe, got = _probe(ctx, WrenchStamped, topics.force_topic("fb_stage1"))
    pub = probe.create_publisher(TwistStamped, topics.velocity_topic("stage1"),
                                 qos.stream_pub(True))
    ex = executor_for(ctx, fb, probe)
    assert spin_until(ex, lambda: pub.get_subscription_count() > 0, 10.0)
    ref = make_controller(cfg, "fb_stage1", enabled=True)
    v = np.array([1e-4])
    pub.publish(twist_msg(v, 500_000, "stage1"))
    assert spin_until(ex, lambda: len(got) == 1, 10.0)
    pub.publish(twist_msg(v, 500_000, "stage1"))  # lockstep retransmission: same stamp
    assert spin_until(ex, lambda: len(got) == 2, 10.0)
    expected = ref.step(v)
    for m in got:
        assert stamp_ns(m.header.stamp) == 500_000 and m.header.frame_id == "stage1"
        np.testing.assert_array_equal(wrench_array(m, 1), expected)
    assert (fb.samples, fb.answers.repeats) == (1, 1)
    pub.publish(twist_msg(np.array([np.nan]), 1_000_000, "stage1"))
    assert spin_until(ex, lambda: len(got) == 3, 10.0)
    assert wrench_array(got[2], 1)[0] == 0.0 and fb.loop.nonfinite == 1
    pub.publish(twist_msg(v, 250_000, "stage1"))  # older than the last: ignored
    spin_until(ex, lambda: False, 0.3)
    assert len(got) == 3 and fb.answers.out_of_order == 1
    ex.shutdown()


def test_enable_service_fades_and_confirms(ctx, cfg):
    """~/enable answers with success and a message and switches the loop's target state."""
    fb = FeedbackControllerNode("fb_stage2", context=ctx, parameter_overrides=overrides(
        cfg, stage=2))
    client_node = rclpy.create_node("client", context=ctx)
    client = client_node.create_client(SetBool, topics.enable_service("fb_stage2"))
    ex = executor_for(ctx, fb, client_node)
    assert spin_until(ex, client.service_is_ready, 10.0)
    assert not fb.loop.enabled
    fut = client.call_async(SetBool.Request(data=True))
    assert spin_until(ex, fut.done, 10.0)
    assert fut.result().success and "fb_stage2 enabled" in fut.result().message
    assert fb.loop.enabled and fb.loop.fader.value == 0.0  # fades in sample by sample
    ex.shutdown()


def test_decoupling_matches_core_and_reorders_channels(ctx, cfg):
    """Channels in any order give the core Decoupler's twists, stamped with the raw stamp."""
    node = SensorDecouplingNode(context=ctx, parameter_overrides=overrides(
        cfg, schedule="lockstep"))
    probe, got = _probe(ctx, TwistStamped, topics.velocity_topic("stage2"))
    pub = probe.create_publisher(JointState, topics.SENSORS_RAW, qos.stream_pub(True))
    ex = executor_for(ctx, node, probe)
    assert spin_until(ex, lambda: pub.get_subscription_count() > 0, 10.0)
    ref = Decoupler(cfg)
    names = list(ref.channel_names)
    raw = np.array([1e-5, 2e-5, -3e-5])
    msg = joint_state(names[::-1], 0, velocity=raw[::-1])
    pub.publish(msg)
    assert spin_until(ex, lambda: len(got) == 1, 10.0)
    np.testing.assert_array_equal(twist_array(got[0], 1), ref.step(raw)[2])
    ex.shutdown()
