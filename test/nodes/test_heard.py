"""Real time: a (re)started controller fades in once the plant has taken one of its forces
(ros/heard.py): the plant echoes the controller process's boot, the controller waits for it."""

from __future__ import annotations

import time

import numpy as np
import rclpy
from geometry_msgs.msg import TwistStamped, WrenchStamped
from node_helpers import executor_for, overrides, realtime_plant, spin_until
from rosmsgs import stamp_ns, twist_msg
from std_msgs.msg import Int64

from dcsms_ros.core import topics
from dcsms_ros.nodes.feedback_controller import FeedbackControllerNode
from dcsms_ros.ros import qos
from dcsms_ros.ros.heard import HeardEcho

PERIOD_NS = 500_000  # 2 kHz


def test_a_controller_fades_in_only_once_the_plant_echoed_its_boot(ctx, cfg):
    """A probe named plant_simulator reads fb_stage1's force (its writer matched, which is all
    the old rule asked) and feeds it a 1 um/s, 2 Hz stage velocity: for 1 s the force stays zero
    and the fade does not start; once the probe echoes the controller's boot on
    plant/heard/fb_stage1 the fade starts from zero and the force follows."""
    fb = FeedbackControllerNode(context=ctx, parameter_overrides=overrides(
        cfg, schedule="realtime", stage=1, enabled=True))
    plant = rclpy.create_node("plant_simulator", namespace=topics.NAMESPACE, context=ctx)
    forces: list[tuple[int, float]] = []
    plant.create_subscription(
        WrenchStamped, topics.force_topic("fb_stage1"),
        lambda m: forces.append((stamp_ns(m.header.stamp), m.wrench.force.z)),
        qos.stream_pub(False))
    vel = plant.create_publisher(TwistStamped, topics.velocity_topic("stage1"),
                                 qos.stream_pub(False))
    echo = plant.create_publisher(Int64, topics.DEFAULT.heard("fb_stage1"), qos.latched())
    ex = executor_for(ctx, fb, plant)
    k = 0

    def feed(seconds: float) -> None:
        nonlocal k
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            v = 1e-6 * np.sin(2 * np.pi * 2.0 * k * PERIOD_NS * 1e-9)
            vel.publish(twist_msg(np.array([v]), k * PERIOD_NS, "stage1"))
            k += 1
            ex.spin_once(timeout_sec=0.001)

    try:
        assert spin_until(ex, lambda: vel.get_subscription_count() > 0
                          and fb.pub.get_subscription_count() > 0, 10.0)
        feed(1.0)
        before = list(forces)
        fader_before = fb.loop.fader.value
        echo.publish(Int64(data=fb.boot_ns))
        k_echo = k
        feed(1.0)
    finally:
        fb.hot.stop()
        ex.shutdown()
        fb.destroy_node()
        plant.destroy_node()
    assert len(before) > 100, len(before)
    assert max(abs(f) for _, f in before) == 0.0 and fader_before == 0.0
    after = [(ns, f) for ns, f in forces if ns >= k_echo * PERIOD_NS]
    nonzero = [f for _, f in after if f != 0.0]
    assert nonzero, "the loop never started after the echo"
    assert fb.loop.fader.value > 0.5  # fading in (0.5 s fade: done within the second)
    # it starts from zero: the first forces are a small part of the last ones
    assert abs(nonzero[0]) < 0.2 * max(abs(f) for f in nonzero)


def test_the_plant_echoes_each_controller_process_once_it_took_its_force(ctx, cfg):
    """A real-time plant echoes fb_stage1's boot after it takes a force of that process, not
    before; a new boot (a restarted process) is echoed after its next force."""
    plant, probe, raw = realtime_plant(ctx, cfg, "heard_probe", 0.3)
    heard: list[int] = []
    probe.create_subscription(Int64, topics.DEFAULT.heard("fb_stage1"),
                              lambda m: heard.append(m.data), qos.latched())
    boot = probe.create_publisher(Int64, topics.DEFAULT.boot("fb_stage1"), qos.latched())
    force = probe.create_publisher(WrenchStamped, topics.force_topic("fb_stage1"),
                                   qos.stream_pub(False))
    ex = executor_for(ctx, plant, probe)

    def answer(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.0005)
            if raw:
                m = WrenchStamped()
                m.header.stamp.sec, m.header.stamp.nanosec = divmod(raw[-1], 1_000_000_000)
                m.header.frame_id = "stage1"
                force.publish(m)

    try:
        boot.publish(Int64(data=111))
        assert spin_until(ex, lambda: len(raw) > 200, 30.0), "the plant did not step"
        assert not spin_until(ex, lambda: bool(heard), 0.5), "echoed without a force"
        answer(0.5)
        assert spin_until(ex, lambda: heard == [111], 5.0), heard
        spin_until(ex, lambda: False, 0.3)  # the old process's last forces taken: it is gone
        boot.publish(Int64(data=222))  # a restarted process
        spin_until(ex, lambda: False, 0.3)
        assert heard == [111], "echoed the new boot before a force of it"
        answer(0.5)
        assert spin_until(ex, lambda: heard == [111, 222], 5.0), heard
    finally:
        plant.hot.stop()
        ex.shutdown()
        plant.destroy_node()
        probe.destroy_node()


def test_the_echo_is_pending_only_while_a_boot_it_learnt_is_not_echoed(ctx):
    """The plant calls took() only while pending: a boot learnt makes it pending, the force of
    that controller echoes it and clears it, a force of another controller does not, and a
    second boot (a restart) makes it pending again."""
    node = rclpy.create_node("heard_pending", namespace="/heard_pending", context=ctx)
    echo = HeardEcho(node, ["fb_stage1", "fb_stage2"])
    try:
        assert not echo.pending
        echo._on_boot("fb_stage1", Int64(data=11))
        echo._on_boot("fb_stage2", Int64(data=21))
        assert echo.pending
        echo.took("fb_stage1")
        assert echo.pending and echo.told == {"fb_stage1": 11, "fb_stage2": 0}
        echo.took("fb_stage2")
        assert not echo.pending
        echo.took("fb_stage2")  # nothing new: no echo, still not pending
        assert not echo.pending and echo.told == {"fb_stage1": 11, "fb_stage2": 21}
        echo._on_boot("fb_stage2", Int64(data=22))  # fb_stage2 restarted
        assert echo.pending
        echo.took("fb_stage1")
        assert echo.pending
        echo.took("fb_stage2")
        assert not echo.pending and echo.told["fb_stage2"] == 22
        echo._on_boot("fb_stage1", Int64(data=11))  # the latched boot again: told already
        assert echo.pending
        echo.took("fb_stage2")
        assert not echo.pending and echo.told["fb_stage1"] == 11
    finally:
        node.destroy_node()
