"""The real-time decoupling steps its filters through every raw sample, answers the newest of
each wake-up, and holds the previous reading over a lost one: its answers are the batch
decoupler's on the whole stream."""

from __future__ import annotations

import time

import numpy as np
import rclpy
from geometry_msgs.msg import TwistStamped
from node_helpers import executor_for, overrides, spin_until
from rosmsgs import joint_state, stamp_ns
from sensor_msgs.msg import JointState

from dcsms_ros.core import topics
from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.core.model import axis_names
from dcsms_ros.nodes.sensor_decoupling import SensorDecouplingNode
from dcsms_ros.ros import qos

SAMPLES = 600
LOST = 300  # never published
BURST = 10  # samples published back to back, then a pause of their duration


def test_every_raw_sample_steps_the_filters_and_a_lost_one_is_held(ctx, cfg):
    """600 raw samples in bursts of 10 (2 kHz on average), sample 300 never sent: the stage-1
    twist answering each of the last samples equals the batch decoupler's over the stream
    with sample 300 replaced by 299. Keep-last 1 (before) skipped samples under bursts and
    stepped nothing for the lost one: its answers differed."""
    node = SensorDecouplingNode(context=ctx, parameter_overrides=overrides(
        cfg, schedule="realtime"))
    probe = rclpy.create_node("every_sample_probe", context=ctx)
    got: dict[int, np.ndarray] = {}

    def on_twist(m: TwistStamped) -> None:
        t = m.twist
        got[stamp_ns(m.header.stamp)] = np.array([t.linear.x, t.linear.y, t.linear.z,
                                                  t.angular.x, t.angular.y, t.angular.z])

    probe.create_subscription(TwistStamped, topics.velocity_topic("stage1"), on_twist,
                              qos.stream_pub(False))
    pub = probe.create_publisher(JointState, topics.SENSORS_RAW, qos.stream_pub(False))
    ex = executor_for(ctx, probe)
    dec = Decoupler(cfg)
    names = list(dec.channel_names)
    period_ns = round(1e9 / cfg.plant.rate_hz)
    rng = np.random.default_rng(5)
    raw = rng.normal(0.0, 1e-5, (SAMPLES, len(names)))
    try:
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0
                          and probe.count_publishers(topics.velocity_topic("stage1")) > 0,
                          10.0)
        time.sleep(0.5)  # both sides matched
        for k0 in range(0, SAMPLES, BURST):
            for k in range(k0, k0 + BURST):
                if k != LOST:
                    pub.publish(joint_state(names, k * period_ns, raw[k]))
            ex.spin_once(timeout_sec=BURST * period_ns * 1e-9)
        last = (SAMPLES - 1) * period_ns
        assert spin_until(ex, lambda: last in got, 5.0), "no answer to the last sample"
    finally:
        node.hot.stop()
        ex.shutdown()
        node.destroy_node()
        probe.destroy_node()
    stream = raw.copy()
    stream[LOST] = raw[LOST - 1]
    want = np.array([dec.step(r)[1] for r in stream])  # ground, stage1, ...
    cols = ["x", "y", "z", "rx", "ry", "rz"]
    pick = [cols.index(a) for a in axis_names(cfg.plant.dof)]
    stamps = sorted(got)
    print(f"{len(stamps)} answers to {SAMPLES - 1} samples")
    assert len(stamps) < SAMPLES - 1  # only the newest of a wake-up is answered
    for ns in stamps:
        np.testing.assert_allclose(got[ns][pick], want[ns // period_ns], rtol=1e-12,
                                   atol=1e-18)
    assert node.held_samples == 1
    assert node.samples == SAMPLES - 1
    assert len(stamps) <= node.published < node.samples
