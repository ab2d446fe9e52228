"""mode_switch in-process: atomic switch, rollback when a controller is absent, trip latch."""

from __future__ import annotations

import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import TwistStamped
from node_helpers import overrides
from rclpy.parameter import Parameter
from rosmsgs import twist_msg
from std_msgs.msg import Int64, String
from std_srvs.srv import Trigger

from dcsms_ros.core import topics
from dcsms_ros.core.modes import Mode
from dcsms_ros.nodes.feedback_controller import FeedbackControllerNode
from dcsms_ros.nodes.mode_switch import ModeSwitchNode
from dcsms_ros.ros import qos
from dcsms_ros.ros.executor import HostExecutor
from dcsms_ros.ros.serialized import serialize


class Graph:
    """mode_switch + fb_stage1 + fb_stage2 (no ff_stage1) and a client node, spun in a thread."""

    def __init__(self, ctx, cfg, **ms_params):
        self.ms = ModeSwitchNode(context=ctx, parameter_overrides=overrides(
            cfg, switch_timeout_s=0.5, **ms_params))
        self.fb = [FeedbackControllerNode(f"fb_stage{i}", context=ctx,
                                          parameter_overrides=overrides(cfg, stage=i))
                   for i in (1, 2)]
        self.client = rclpy.create_node("client", context=ctx)
        self.modes: list[str] = []
        self.client.create_subscription(String, topics.MODE, lambda m: self.modes.append(m.data),
                                        qos.latched())
        # the host's executor, as a node process spins mode_switch (a multi-threaded one left
        # the exceptions of callbacks that ran into the teardown unretrieved, printed on stderr
        # when collected: inside a later test's capture in CI)
        self.ex = HostExecutor(context=ctx)
        for n in (self.ms, *self.fb, self.client):
            serialize(n)  # as the host does: callbacks one at a time with the hot loop
            self.ex.add_node(n)
        self._stop = False
        self.thread = __import__("threading").Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        # not ex.spin(): shutdown() from another thread destroys the executor's guard
        # condition while spin() may be building its wait set (an AttributeError in CI)
        while not self._stop:
            self.ex.spin_once(timeout_sec=0.05)

    def call(self, service: str) -> Trigger.Response:
        cli = self.client.create_client(Trigger, service)
        assert cli.wait_for_service(timeout_sec=10.0), service
        fut = cli.call_async(Trigger.Request())
        deadline = time.monotonic() + 10.0
        while not fut.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        return fut.result()

    def wait(self, cond, timeout=10.0) -> bool:
        deadline = time.monotonic() + timeout
        while not cond() and time.monotonic() < deadline:
            time.sleep(0.02)
        return cond()

    def close(self):
        self._stop = True
        self.thread.join(timeout=10.0)
        self.ex.shutdown(timeout_sec=2.0)


def test_switch_and_rollback_when_a_controller_is_absent(ctx, cfg):
    """DFBC switches; FBC+FFC without ff_stage1 fails, names it and restores DFBC everywhere."""
    g = Graph(ctx, cfg)
    try:
        assert g.wait(lambda: g.modes and g.modes[-1] == "Passive")
        r = g.call(topics.set_mode_service("dfbc"))
        assert r.success, r.message
        assert g.wait(lambda: g.modes[-1] == "DFBC")
        assert [f.loop.enabled for f in g.fb] == [True, True]
        r = g.call(topics.set_mode_service("fbc_ffc"))
        assert not r.success
        assert "ff_stage1" in r.message and "rolled back to DFBC" in r.message
        # fb_stage2 had been switched off for FBC+FFC; the rollback switched it on again
        assert [f.loop.enabled for f in g.fb] == [True, True]
        time.sleep(0.2)
        assert g.modes[-1] == "DFBC" and g.ms.mode.label == "DFBC"
        r = g.call(topics.set_mode_service("passive"))
        assert r.success and [f.loop.enabled for f in g.fb] == [False, False]
    finally:
        g.close()


@pytest.mark.parametrize("supervised", [False, True], ids=["latch", "supervisor"])
def test_instability_trip_latches_passive_until_reset(ctx, cfg, supervised):
    """A large in-band oscillation on stage 1 trips to Passive, blocks switching until reset.
    Without the supervisor the trip latches; with it (no floor published: a quiet floor) it is
    an instability, TRIPPED, and a switch is refused until the floor has been quiet, or until
    reset_trip."""
    g = Graph(ctx, cfg, initial_mode="fbc", **{"control.trip_rms_mps": 1e-4,
                                                "supervisor.enabled": supervised})
    try:
        pub = g.client.create_publisher(TwistStamped, topics.velocity_topic("stage1"),
                                        qos.stream_pub(False))
        assert g.wait(lambda: pub.get_subscription_count() > 0)
        assert g.wait(lambda: g.fb[0].loop.enabled)  # reconciled to the initial mode
        rate = cfg.plant.rate_hz
        t0 = time.monotonic()
        for k in range(int(0.5 * rate)):  # 0.5 s of a 10 Hz, 1 mm/s oscillation
            pub.publish(twist_msg(np.array([1e-3 * np.sin(2 * np.pi * 10 * k / rate)]),
                                  int(k * 1e9 / rate), "stage1"))
            if k % 100 == 0:
                time.sleep(0.005)
        assert g.wait(lambda: g.ms.tripped, 5.0)
        print(f"\ntrip latched {time.monotonic() - t0:.2f} s after the oscillation started: "
              f"{g.ms.trip_reason}")
        assert ("on a quiet floor" if supervised else "stage1 velocity RMS") in g.ms.trip_reason
        assert g.wait(lambda: g.modes[-1] == "Passive") and not g.fb[0].loop.enabled
        r = g.call(topics.set_mode_service("fbc"))
        assert not r.success
        assert ("supervisor TRIPPED" if supervised else "reset_trip") in r.message, r.message
        time.sleep(1.0)  # let the monitor take every sample still queued (they would re-trip)
        r = g.call(topics.RESET_TRIP)
        assert r.success and "trip cleared" in r.message
        r = g.call(topics.set_mode_service("fbc"))
        assert r.success and g.fb[0].loop.enabled
    finally:
        g.close()


def test_restarted_controller_is_given_the_current_mode(ctx, cfg):
    """A new boot id on a controller's ``boot`` topic (a killed process restarted while its
    old enable service still looks alive) makes mode_switch send it the current mode's
    state."""
    g = Graph(ctx, cfg)
    try:
        assert g.call(topics.set_mode_service("dfbc")).success
        assert g.wait(lambda: "fb_stage1" in g.ms.ctl.boots and g.ms.ctl.ready["fb_stage1"])
        time.sleep(0.6)  # the reconcile that saw the services appear has told them already
        # the restarted process came up disabled (its command line said Passive), and the
        # service never looked gone, so the 0.5 s reconcile has nothing to notice
        g.fb[0].loop.enable(False)
        time.sleep(1.2)
        assert not g.fb[0].loop.enabled
        pub = g.client.create_publisher(Int64, topics.DEFAULT.boot("fb_stage1"), qos.latched())
        assert g.wait(lambda: pub.get_subscription_count() > 0)
        pub.publish(Int64(data=1))
        assert g.wait(lambda: g.fb[0].loop.enabled, timeout=5.0), "restart not noticed"
        assert g.ms.mode.label == "DFBC" and g.fb[1].loop.enabled
    finally:
        g.close()


def test_supervisor_parameters_change_at_run_time(ctx, cfg):
    """``ros2 param set`` on mode_switch: a supervisor parameter applies to the running
    supervisor (from its next checkpoint); an out-of-range one is rejected with the reason."""
    g = Graph(ctx, cfg)
    try:
        assert g.ms.watch.sfeed is not None and g.ms.watch.sfeed.sup.s.recover_after_s == 5.0
        ok = g.ms.set_parameters([Parameter("supervisor.recover_after_s", value=9.0),
                                  Parameter("supervisor.ride_mode", value="passive")])
        assert all(r.successful for r in ok), ok
        assert g.ms.watch.sfeed.sup.s.recover_after_s == 9.0
        assert g.ms.watch.sfeed.sup.s.ride_mode is Mode.PASSIVE
        bad = g.ms.set_parameters([Parameter("supervisor.hold_s", value=-1.0)])
        assert not bad[0].successful and "supervisor.hold_s" in bad[0].reason, bad
        assert g.ms.watch.sfeed.sup.s.hold_s == 2.0
    finally:
        g.close()
