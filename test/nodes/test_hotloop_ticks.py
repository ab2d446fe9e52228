"""The hot loop's ticks (ros/hotloop.py): a wake-up runs them at once, a loop with nothing to
wait on sleeps until its tick or a wake-up, a lazy tick runs only once its wait passed."""

from __future__ import annotations

import threading
import time

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Header

from dcsms_ros.ros import qos
from dcsms_ros.ros.hotloop import IDLE_S
from dcsms_ros.ros.hotpath import HotPath


def _wake_runs_the_tick(hot: HotPath, ticks: list[float], within_s: float) -> None:
    """``hot.wake()`` from this thread makes the loop call the tick (which appends its time
    to ``ticks``) within ``within_s``."""
    n, t0 = len(ticks), time.monotonic()
    hot.wake()
    while len(ticks) == n:
        assert time.monotonic() - t0 < 2.0, "a wake() did not run the tick"
        time.sleep(0.0005)
    assert ticks[-1] - t0 < within_s


def test_a_loop_without_dds_subscriptions_sleeps_until_woken(ctx) -> None:
    """A loop serving no DDS subscription (composed, every topic in-process) waits on an
    event, not an rcl wait set: a wake() from another thread runs its tick at once, long
    before the loop's idle wake-up (IDLE_S), and stop() ends it at once."""
    node = Node("tick_only", context=ctx)
    hot = HotPath(node, threading.Lock())
    ticks: list[float] = []

    def tick() -> float:
        ticks.append(time.monotonic())
        return 10.0

    hot.set_tick(tick)
    try:
        hot.start()
        assert hot.loop is not None and not hot.subs
        end = time.monotonic() + 5.0
        while not ticks:
            assert time.monotonic() < end, "the loop never ticked"
            time.sleep(0.01)
        time.sleep(0.5)
        idle = np.diff(ticks)
        assert idle.min() > 0.8 * IDLE_S  # asleep between idle wake-ups
        for _ in range(5):
            _wake_runs_the_tick(hot, ticks, within_s=0.25 * IDLE_S)
            time.sleep(0.02)
        t0 = time.monotonic()
        hot.stop()
        assert time.monotonic() - t0 < 1.0 and hot.loop._thread is None
    finally:
        hot.stop()
        node.destroy_node()


def test_a_lazy_tick_runs_when_its_wait_passed_or_at_a_wake_not_at_every_message(ctx) -> None:
    """A lazy tick (a controller's watchdog) is called once the wait it returned has passed,
    not after each of the messages the loop serves meanwhile, and at once after a wake()."""
    node, talker = Node("lazy_tick", context=ctx), Node("lazy_tick_talker", context=ctx)
    hot = HotPath(node, threading.Lock())
    got: list[bytes] = []
    ticks: list[float] = []
    wait_s = 0.1

    def tick() -> float:
        ticks.append(time.monotonic())
        return wait_s

    hot.subscribe(Header, "/lazy_tick", got.append, qos.stream_sub(True), raw=True)
    hot.set_tick(tick, lazy=True)
    pub = talker.create_publisher(Header, "/lazy_tick", qos.stream_pub(True))
    try:
        hot.start()
        end = time.monotonic() + 20.0
        while pub.get_subscription_count() == 0 or not ticks:
            assert time.monotonic() < end, "no match or no first tick"
            time.sleep(0.01)
        t0, n0 = time.monotonic(), len(ticks)
        while time.monotonic() - t0 < 1.0:
            pub.publish(Header())
            time.sleep(0.002)
        ticked = ticks[n0:]
        assert len(got) > 100  # the loop woke for each of them
        assert 5 <= len(ticked) <= 1.0 / wait_s + 2, (len(ticked), len(got))
        assert np.diff(ticked).min() >= 0.9 * wait_s
        for _ in range(3):
            _wake_runs_the_tick(hot, ticks, within_s=0.25 * wait_s)
    finally:
        hot.stop()
        node.destroy_node()
        talker.destroy_node()
