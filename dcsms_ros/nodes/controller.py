"""Shared adapter of the feedback and feedforward controller nodes.

One sample: ``/dcsms/velocity/<body>`` (TwistStamped) -> ``loop.step`` -> ``/dcsms/force/<id>``
(WrenchStamped, frame_id = the stage the actuators push, stamp = the input's stamp), both as
serialized CDR (:mod:`.wire`: no Python message objects per sample). The node
publishes for every sample, zero while disabled, because the lockstep plant waits for every
controller. A repeated stamp (lockstep retransmission) is answered from the cache; an older stamp
is ignored. ``~/enable`` (std_srvs/SetBool) fades the loop in or out over
``control.fade_time_s``; parameter ``enabled`` starts it at full gain in lockstep, as the batch
engine starts the controllers of its initial mode, and fades it in from zero in real time (a
restarted controller rejoins a running plant without a kick): the loop starts, primed, only once
the plant's reader matched the force publisher (zero force until then).

Real time only: a watchdog publishes zero force while no input arrived for
``control.input_timeout_s`` (steady wall clock; on the hot thread, whose wait ends at the
deadline, else a timer every quarter timeout). In lockstep the plant's own timeout covers a
silent input, and a pause of the plant is not a fault.
"""

from __future__ import annotations

import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_srvs.srv import SetBool

from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import make_controller
from dcsms_ros.core.modes import controller_stage
from dcsms_ros.errors import ConfigError
from dcsms_ros.nodes import qos
from dcsms_ros.nodes.guard import MAX_VELOCITY_MPS, InputGuard
from dcsms_ros.nodes.hotpath import HotPath
from dcsms_ros.nodes.msgs import status, to_stamp
from dcsms_ros.nodes.params import (
    FirstSampleGate,
    NodeConfig,
    declare_local,
    declare_observed,
    declare_schedule,
)
from dcsms_ros.nodes.runtime import Stoppable, wait_acked
from dcsms_ros.nodes.wire import StampedWriter, read_stamped

#: Longest hold of the first lockstep answer while readers match, s.
MATCH_TIMEOUT_S = 5.0


class ControllerNode(Node, Stoppable):
    """Base of :class:`FeedbackControllerNode` and :class:`FeedforwardControllerNode`."""

    def setup(self, cid: str, select, body: str) -> None:
        """Declare parameters, build the core loop and the ROS interfaces.

        Parameters
        ----------
        cid : str
            Controller id (``fb_stage1`` …, ``ff_stage1``); must equal the node name.
        select : callable
            Parameter selector (see :mod:`.params`).
        body : str
            Body whose velocity is the input (``ground`` or ``stage<i>``).
        """
        if self.get_name() != cid:
            raise ConfigError(f"node {self.get_name()}: controller {cid} must run as node "
                              f"'{cid}' (add --ros-args -r __node:={cid}) so that its enable "
                              f"service is {topics.enable_service(cid)}")
        self.cid = cid
        # the hot thread runs _on_velocity; executor callbacks touching the loop take the lock
        self._lock = threading.RLock()
        self.hot = HotPath(self, self._lock)
        self.params = NodeConfig(self, select, self._on_change_locked)
        self.lockstep = declare_schedule(self) == "lockstep"
        # the actuator side: the plant in simulation, the rig's actuator driver on hardware
        self.force_reader = declare_local(self, "force_reader", "plant_simulator", "Real "
                                          "time: node whose reader of the force topic must be "
                                          "matched before the loop starts (empty: any reader)")
        enabled = declare_local(self, "enabled", False, "Start enabled at full gain (no fade), "
                                "as the batch engine starts its initial mode")
        self.observed = declare_observed(self)
        # lockstep: the first sample is answered only once the output reaches every reader
        # (the plant retransmits it), so an observer misses nothing; the loop is not stepped
        self._gate = FirstSampleGate(self, self.lockstep, MATCH_TIMEOUT_S)
        cfg = self.params.cfg
        # lockstep starts at full gain, as the batch engine does; real time fades in from zero,
        # so a (re)started controller joins a running plant without a kick
        self.loop = make_controller(cfg, cid, enabled=bool(enabled) and self.lockstep)
        if enabled and not self.lockstep:
            self.loop.enable(True)
        self.dof = cfg.plant.dof
        self.rate = cfg.plant.rate_hz
        self.guard = InputGuard(self, f"{cid} velocity", MAX_VELOCITY_MPS)
        self.frame = f"stage{controller_stage(cid)}"
        self.writer = StampedWriter(WrenchStamped, self.frame, self.dof)
        self.input_timeout_s = cfg.control.input_timeout_s
        self.pub = self.create_publisher(WrenchStamped, topics.force_topic(cid),
                                         qos.stream_pub(self.lockstep))
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, qos.status())
        self.hot.subscribe(TwistStamped, topics.velocity_topic(body), self._on_velocity,
                           qos.stream_sub(self.lockstep), raw=True)
        self.create_service(SetBool, "~/enable", self._on_enable)
        self._zero = np.zeros(self.dof)
        self.last_ns = -1
        self._cache: bytes | None = None
        self._t_in = None
        self.stale = False
        self.samples = self.repeats = self.out_of_order = 0
        self.nonfinite_out = self.stale_events = 0
        self.stale_at_mono_ns = 0
        self.changed_at_ns = -1
        self._seen = (0, 0)
        self.boot_ns = time.time_ns()  # tells mode_switch a restarted process from the old one
        # real time: the loop is stepped (its fade runs) only once its output reaches the plant
        self._linked = self.lockstep
        self._link_check_ns = -1
        self._plant_seen: float | None = None
        if not self.lockstep and self.hot.on:
            # on the hot thread: its wait times out at the deadline, so a silent input is
            # caught on time without waking the executor at 400 Hz (~6 % of a core)
            self.hot.set_tick(self._hot_watchdog)
        elif not self.lockstep:
            # steady clock: sim time only advances with /clock (100 Hz), too coarse for 10 ms
            self.create_timer(max(self.input_timeout_s / 4.0, 1e-3), self._watchdog,
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.create_timer(1.0, self._report, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"{cid}: input {topics.velocity_topic(body)}, output "
                               f"{topics.force_topic(cid)}, "
                               f"{'enabled' if enabled else 'disabled'}")
        self.hot.start()
        self._report()  # at once: mode_switch learns of a restart before the loop starts

    # -- the loop ----------------------------------------------------------------------------

    def _on_velocity(self, buf: bytes) -> None:
        ns, x = read_stamped(buf, TwistStamped, self.dof)
        # implausible (non-finite, > 10 m/s): counted and logged here, NaN for the loop, which
        # answers it with zero force (lockstep goes on) and leaves its filters untouched
        x = self.guard.clean(x, np.nan)
        if ns == self.last_ns and self._cache is not None:
            self.repeats += 1
            self.pub.publish(self._cache)
            return
        if ns < self.last_ns:
            self.out_of_order += 1
            return
        if not self._gate.ready([self.pub], self.observed):
            return
        if not self.lockstep and self.last_ns >= 0 and self._linked:
            # real time drops samples under load (keep-last 1): the fade follows the stamps,
            # so a switch or a trip fades in control.fade_time_s of plant time, not messages;
            # a fade-in skips at most an input timeout: a longer gap (a stall, or the old first
            # sample a just started node may take) must not become a step of the gain
            gap = min(round((ns - self.last_ns) * self.rate / 1e9) - 1, 100_000)
            if self.loop.enabled:
                gap = min(gap, round(self.input_timeout_s * self.rate))
            for _ in range(gap):
                self.loop.fader.step()
        self.last_ns = ns
        self._t_in = time.monotonic()
        if self.stale:
            self.stale = False
            self.get_logger().info(f"{self.cid}: input is back")
        if not self._linked and self._reaches_actuators(ns):
            self._linked = True
            self.loop.prime(x)  # joining a running plant: no filter start-up transient
        w = self.loop.step(x) if self._linked else self._zero
        if not np.isfinite(w).all():  # defensive: a NaN must never reach an actuator
            self.nonfinite_out += 1
            w = self._zero
        self._cache = self.writer.encode(ns, w)
        self.pub.publish(self._cache)
        self.samples += 1
        seen = (self.loop.nonfinite, self.loop.saturations)
        if seen != self._seen:
            if seen[0] != self._seen[0]:
                self.get_logger().warning(f"{self.cid}: non-finite input ignored (total "
                                          f"{seen[0]})", throttle_duration_sec=2.0)
            if seen[1] != self._seen[1]:
                self.get_logger().warning(f"{self.cid}: actuator saturation (total {seen[1]} "
                                          f"samples)", throttle_duration_sec=2.0)
            self._seen = seen

    def _reaches_actuators(self, ns: int) -> bool:
        """Real time: True once the ``force_reader`` node's reader and every other reader of
        the force topic this node sees matched the publisher (checked every 10 ms of stamps;
        an incompatible reader holds it MATCH_TIMEOUT_S at most). Before that the fade would
        run unheard: a restarted controller's discovery can take a second, and it rejoined at
        full gain."""
        if ns - self._link_check_ns < 10_000_000 or self.pub.get_subscription_count() == 0:
            return False
        self._link_check_ns = ns
        infos = self.get_subscriptions_info_by_topic(self.pub.topic_name)
        if self.force_reader and not any(i.node_name == self.force_reader for i in infos):
            return False
        if self._plant_seen is None:
            self._plant_seen = time.monotonic()
        return (self.pub.get_subscription_count() >= len(infos)
                or time.monotonic() - self._plant_seen > MATCH_TIMEOUT_S)

    def _watchdog(self) -> None:
        with self._lock:
            self._watchdog_locked()

    def _hot_watchdog(self) -> float | None:
        """Hot-thread tick: the watchdog when due; seconds until it is due again."""
        if self._t_in is None:
            return None
        left = self._t_in + self.input_timeout_s - time.monotonic()
        if left > 0.0:
            return left
        self._watchdog_locked()  # zero force, repeated every quarter timeout while silent
        return max(self.input_timeout_s / 4.0, 1e-3)

    def _watchdog_locked(self) -> None:
        if self._t_in is None:
            return
        if time.monotonic() - self._t_in <= self.input_timeout_s:
            return
        now = self.get_clock().now()
        if not self.stale:
            self.stale = True
            self.stale_events += 1
            self.stale_at_mono_ns = time.monotonic_ns()  # compared with a kill time by tests
            self.get_logger().warning(f"{self.cid}: no input for {self.input_timeout_s:g} s: "
                                      f"zero force", throttle_duration_sec=2.0)
        self.pub.publish(self.writer.encode(now.nanoseconds, self._zero))

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response):
        with self._lock:
            was = self.loop.enabled
            self.loop.enable(bool(request.data))
        word = {True: "enabled", False: "disabled"}
        response.success = True
        response.message = (f"{self.cid} {word[bool(request.data)]} (was {word[was]}; fade "
                            f"{self.params.cfg.control.fade_time_s:g} s)")
        self.get_logger().info(response.message)
        return response

    # -- parameters --------------------------------------------------------------------------
    def _on_change_locked(self, cfg: SystemConfig, changed: set[str]) -> None:
        with self._lock:
            self._on_change(cfg, changed)

    def _on_change(self, cfg: SystemConfig, changed: set[str]) -> None:
        """Rebuild the loop from the new tuning, keeping what state can be kept."""
        self.input_timeout_s = cfg.control.input_timeout_s
        self.changed_at_ns = self.last_ns  # the newest sample before the change (diagnostics)
        old = self.loop
        new = make_controller(cfg, self.cid, enabled=old.enabled)
        if "control.fade_time_s" not in changed:
            new.fader = old.fader  # keep the gain ramp exactly where it is
        # same filter structure (a gain or corner tweak): carry the delay states over so the
        # output continues instead of restarting from rest
        fo, fn = getattr(old, "_filter", None), getattr(new, "_filter", None)
        if fo is not None and fn is not None:
            so, sn = fo.get_state(), fn.get_state()
            if so.shape == sn.shape:
                fn.set_state(so)
        new.saturations, new.nonfinite = old.saturations, old.nonfinite
        self.loop = new

    # -- reporting ---------------------------------------------------------------------------
    def _report(self) -> None:
        level = DiagnosticStatus.WARN if self.stale else DiagnosticStatus.OK
        arr = DiagnosticArray()
        arr.header.stamp = to_stamp(max(self.last_ns, 0))
        arr.status = [status(self.cid, level, "stale input: zero force" if self.stale else
                             ("enabled" if self.loop.enabled else "disabled"), {
            "enabled": self.loop.enabled, "gain": f"{self.loop.fader.value:.3f}",
            "samples": self.samples, "repeats": self.repeats,
            "out_of_order": self.out_of_order, "saturations": self.loop.saturations,
            "nonfinite_inputs": self.loop.nonfinite, "nonfinite_outputs": self.nonfinite_out,
            "rejected_inputs": self.guard.rejected,
            "stale_at_mono_ns": self.stale_at_mono_ns,
            "params_changed_at_ns": self.changed_at_ns,
            "stale_events": self.stale_events, "boot_ns": self.boot_ns})]
        self.pub_diag.publish(arr)

    def close(self) -> None:
        """Give reliable observers a moment to receive the last commands and the final
        counters (clean exit)."""
        self._report()
        wait_acked([self.pub, self.pub_diag])
