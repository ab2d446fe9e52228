"""Plant simulator node: the cascade, its geophones, disturbances and actuators.

Publishes ``/clock``, the raw geophone channels, the true body velocities and the forces the
actuators applied; subscribes to every controller's force command. Two schedules (parameter
``schedule``):

* ``lockstep`` - sample k is published, and the plant advances to k+1 only when it holds the
  wrench of every expected controller stamped with sample k's time. The same
  :class:`~dcsms_ros.core.simulator.PlantSimulator` calls happen in the same order as in
  :func:`dcsms_ros.core.engine.simulate`, so the trajectory is identical to the batch engine's.
  A reply missing after ``control.lockstep_timeout_s`` (wall clock) is a fault: zero force for
  that controller, counted and logged; after ``absent_after`` faults in a row the controller is
  *absent* and not waited for until it publishes again. If a reply is missing after
  ``lockstep_retry_s`` the sample is published again with the same stamp (the decoupling and
  controller nodes answer a repeated stamp from their cache, so nothing steps twice).
* ``realtime`` - the plant steps on the wall clock at ``plant.rate_hz``, using the newest force
  of each controller; a force older than ``control.input_timeout_s`` counts as zero.

Startup handshake: sample 0 is published only once every force topic has a publisher, the raw
topic a subscriber, and each topic in ``wait_for_subscribers`` a subscriber outside the graph
(a recorder or test probe), or after ``handshake_timeout_s``.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState

from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import controller_ids
from dcsms_ros.core.simulator import PlantSimulator
from dcsms_ros.nodes import qos
from dcsms_ros.nodes.guard import FORCE_LIMIT_FACTOR, InputGuard
from dcsms_ros.nodes.hotpath import HotPath
from dcsms_ros.nodes.msgs import sample_ns, status, to_stamp
from dcsms_ros.nodes.params import (
    GRAPH_NODES,
    SELECTORS,
    NodeConfig,
    declare_observed,
    declare_schedule,
    publishers_matched,
)
from dcsms_ros.nodes.plant_options import declare_plant_options, replayed_ground
from dcsms_ros.nodes.runtime import Stoppable, main_for, wait_acked
from dcsms_ros.nodes.wire import JointStateWriter, StampedWriter, read_frame, read_stamped

#: Real time: at most this many samples are computed in one timer callback to catch up.
MAX_BURST = 20
#: Seconds the handshake waits after the graph looks connected, so DDS endpoints match too.
SETTLE_S = 0.2


class PlantSimulatorNode(Node, Stoppable):
    """ROS adapter around :class:`~dcsms_ros.core.simulator.PlantSimulator`."""

    def __init__(self, **kwargs) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__("plant_simulator", **kwargs)
        self.params = NodeConfig(self, SELECTORS["plant_simulator"], self._on_change)
        cfg = self.params.cfg
        n = cfg.plant.num_stages
        self.schedule = declare_schedule(self)
        self.lockstep = self.schedule == "lockstep"
        opts = declare_plant_options(self, n)
        self.duration_s = opts.duration_s
        # the excitation node answers each sample like a controller (excitation.py); the
        # plant adds its wrench after the controllers' (as the batch engine's excite=)
        self.controllers = list(opts.controllers) + ([topics.EXCITATION_ID]
                                                     if opts.excitation else [])
        self._exc_stage: int | None = None  # 0-based stage named by the excitation's frame
        self.retry_s = opts.retry_s
        self.absent_after = opts.absent_after
        self.handshake_timeout_s = opts.handshake_timeout_s
        self.observed = declare_observed(self)
        self.publish_truth = opts.publish_truth
        self.timing_file = opts.timing_file
        self.sim = PlantSimulator(cfg, ground=replayed_ground(opts.ground_from, cfg))
        self.force_guard = InputGuard(self, "force command", FORCE_LIMIT_FACTOR * max(
            a.limit for a in self.sim.allocators))
        self.dof = cfg.plant.dof
        self.rate = cfg.plant.rate_hz
        self.bodies = topics.body_names(n)
        self.channel_names = [c.name for c in self.sim.channels]
        self.clock_every = max(1, int(round(cfg.plant.rate_hz / opts.clock_rate_hz)))
        self.total_steps = int(round(self.duration_s * self.rate)) if self.duration_s else 0
        self._timeouts(cfg)

        pub_qos = qos.stream_pub(self.lockstep)
        self.pub_clock = self.create_publisher(ClockMsg, topics.CLOCK, qos.clock())
        self.pub_raw = self.create_publisher(JointState, topics.SENSORS_RAW, pub_qos)
        self.pub_applied = self.create_publisher(JointState, topics.ACTUATORS_APPLIED, pub_qos)
        self.pub_truth = [self.create_publisher(TwistStamped, topics.truth_topic(b), pub_qos)
                          for b in self.bodies] if self.publish_truth else []
        self.pub_diag = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, qos.status())
        sub_qos = qos.stream_sub(self.lockstep)
        # forces are taken by the hot thread (hotpath.py); the executor keeps handshake,
        # lockstep timeouts/retransmissions and reports, under the same lock
        self._lock = threading.RLock()
        self.hot = HotPath(self, self._lock)
        # real time: the forces are held values, so the hot thread does not wake for each one:
        # it drains them at every sample (arrival times from the DDS reception stamps)
        self._drained = not self.lockstep and self.hot.on
        self._force_subs = []
        for cid in self.controllers:
            if self._drained:
                self._force_subs.append(
                    (cid, self.hot.detached(WrenchStamped, topics.force_topic(cid), sub_qos,
                                            raw=True)))
            else:
                self.hot.subscribe(WrenchStamped, topics.force_topic(cid),
                                   lambda m, c=cid: self._on_force(c, m), sub_qos, raw=True)
        # the per-sample messages are serialized here directly (wire.py: no message objects)
        self._w_raw = JointStateWriter(self.channel_names, "velocity")
        self._w_applied = JointStateWriter(self.sim.actuator_names, "effort")
        self._w_truth = [StampedWriter(TwistStamped, b, self.dof) for b in self.bodies]
        self._wall_to_mono = time.monotonic_ns() - time.time_ns()
        self._applied: tuple[np.ndarray, int] | None = None
        self._t_pub: list[int] = []  # timing_file: monotonic ns of each sample's publication
        self._lat: dict[str, list[int]] = {c: [] for c in self.controllers}
        self._cpu = [0.0, 0.0]
        self._zero = np.zeros(self.dof)
        # lockstep state
        self._ns = 0
        self._waiting = False
        self._got: dict[str, np.ndarray] = {}
        self._t_sent = self._t_retx = 0.0
        self._absent: set[str] = set()
        self._consec = dict.fromkeys(self.controllers, 0)
        self.faults = dict.fromkeys(self.controllers, 0)
        self.retransmits = 0
        # real-time state
        self._held: dict[str, tuple[np.ndarray, float]] = {}
        self._stale = dict.fromkeys(self.controllers, True)
        self.stale_events = dict.fromkeys(self.controllers, 0)
        # when (CLOCK_MONOTONIC ns, sample) each force last went stale: the fault tests compare
        # it with the time they killed the controller (the same clock in every process)
        self.stale_at: dict[str, tuple[int, int]] = dict.fromkeys(self.controllers, (0, 0))
        self.overruns = 0
        self._t0 = self._t_run = 0.0
        # bookkeeping
        self.started = False
        self._t_start = time.monotonic()
        self._ready_at: float | None = None
        self._rate_mark = (0, time.monotonic())
        self.achieved_hz = 0.0
        self._nonfinite_seen = 0
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        # real time steps on the hot thread (set_tick) unless the hot path is off
        tick = 1.0 / self.rate if not self.lockstep and not self.hot.on else 0.005
        self._tick_timer = self.create_timer(tick, self._tick_locked, clock=steady)
        if not self.lockstep:
            self.hot.set_tick(self._hot_tick)
        self.create_timer(opts.status_period_s, self._report, clock=steady)
        self.get_logger().info(
            f"{self.schedule} at {self.rate:g} Hz, {n} stages ({cfg.plant.fidelity}), "
            f"controllers {self.controllers}, {len(self.channel_names)} channels, "
            f"{self.sim.num_actuators} actuators, seed {cfg.disturbance.seed}")
        self.hot.start()

    # -- parameters ------------------------------------------------------------------------
    def _timeouts(self, cfg: SystemConfig) -> None:
        self.input_timeout_s = cfg.control.input_timeout_s
        self.lockstep_timeout_s = cfg.control.lockstep_timeout_s

    def _on_change(self, cfg: SystemConfig, changed: set[str]) -> None:
        # only timeouts are mutable here: the plant and its disturbances are fixed at start
        self._timeouts(cfg)

    # -- handshake ---------------------------------------------------------------------------
    def _missing(self) -> list[str]:
        """What the graph still lacks before sample 0 can be published."""
        out = [f"publisher of {topics.force_topic(c)}" for c in self.controllers
               if self.count_publishers(topics.force_topic(c)) == 0]
        if self.count_subscribers(topics.SENSORS_RAW) == 0:
            out.append(f"subscriber of {topics.SENSORS_RAW}")
        graph = set(GRAPH_NODES) | set(controller_ids(len(self.bodies) - 1))
        for topic in self.observed:
            infos = self.get_subscriptions_info_by_topic(topic)
            if not any(i.node_name not in graph for i in infos):
                out.append(f"observer of {topic}")
        own = [self.pub_raw, self.pub_applied, *self.pub_truth]
        if not out and not publishers_matched(self, own, self.observed):
            out.append("DDS matching of the plant's publishers")
        return out

    def _handshake(self, now: float) -> None:
        missing = self._missing()
        if missing and now - self._t_start < self.handshake_timeout_s:
            self._ready_at = None
            return
        if missing:
            self.get_logger().warning(f"starting without: {', '.join(missing)}")
        elif self._ready_at is None:
            self._ready_at = now
            return
        elif now - self._ready_at < SETTLE_S:
            return
        self.started = True
        self._t0 = now  # real time: moved on when a backlog is dropped
        self._t_run = now  # not moved: the wall time of the whole run
        self._cpu[0] = time.process_time()
        self._rate_mark = (self.sim.k, now)
        if self._drained:
            self._tick_timer.cancel()  # real time steps on the hot thread: nothing left to poll
        self.hot.wake()
        self.get_logger().info("graph connected: stepping")

    # -- stepping ----------------------------------------------------------------------------
    def _tick_locked(self) -> None:
        with self._lock:
            self._tick()

    def _hot_tick(self) -> float | None:
        """Real time on the hot thread: step what is due; seconds until the next sample."""
        if not self.started or self.finished:
            return None
        for cid, sub in self._force_subs:
            with sub.handle:
                while (got := sub.handle.take_message(WrenchStamped, True)) is not None:
                    self._on_force(cid, got[0], got[1]["received_timestamp"]
                                   + self._wall_to_mono)
        self._realtime(time.monotonic())
        return self._t0 + self.sim.k / self.rate - time.monotonic()

    def _tick(self) -> None:
        now = time.monotonic()
        if self.finished:
            return
        if not self.started:
            self._handshake(now)
            if not self.started:
                return
        if not self.lockstep:
            if not self.hot.on:
                self._realtime(now)
        elif not self._waiting:
            self._pump()
        elif now - self._t_sent > (self.lockstep_timeout_s if self.sim.k else
                                   self.handshake_timeout_s):
            # sample 0 may wait for the whole handshake time: the other nodes hold their first
            # answer until their publishers matched every reader (no observer misses it)
            self._lockstep_timeout()
        elif now - self._t_retx > self.retry_s:
            self.pub_raw.publish(self._raw_msg)
            self._t_retx = now
            self.retransmits += 1

    def _publish_sample(self) -> None:
        """Publish sample k: raw channels first (the control path waits for them), then the
        previous sample's applied forces, clock and true velocities. The core calls keep the
        engine's order; observer topics nobody subscribes to are not serialized at all."""
        ns = sample_ns(self.sim.k, self.rate)
        self._ns = ns
        if self.timing_file:
            self._t_pub.append(time.monotonic_ns())
        truth = self.sim.truth().copy()
        raw = self.sim.measure()
        self._raw_msg = self._w_raw.encode(ns, raw)
        self.pub_raw.publish(self._raw_msg)
        self._flush_applied()
        if self.sim.k % self.clock_every == 0:
            self.pub_clock.publish(ClockMsg(clock=to_stamp(ns)))
        for b, (pub, v) in enumerate(zip(self.pub_truth, truth, strict=False)):
            if pub.get_subscription_count():
                pub.publish(self._w_truth[b].encode(ns, v))

    def _flush_applied(self) -> None:
        """Publish the applied forces held back by :meth:`_advance` (lockstep)."""
        if self._applied is not None:
            applied, ns = self._applied
            self._applied = None
            if self.pub_applied.get_subscription_count():
                self.pub_applied.publish(self._w_applied.encode(ns, applied))

    def _advance(self, wrenches: dict[str, np.ndarray]) -> None:
        exc = None
        if topics.EXCITATION_ID in wrenches:
            w = wrenches.pop(topics.EXCITATION_ID)
            exc = np.zeros((len(self.bodies) - 1, self.dof))
            if self._exc_stage is not None:
                exc[self._exc_stage] = w
        applied = self.sim.advance(wrenches, exc)
        # lockstep: published after the next raw sample, off the loop's critical path
        self._applied = (applied, self._ns)
        if not self.lockstep:
            self._flush_applied()
        if self.sim.nonfinite_inputs != self._nonfinite_seen:
            self._nonfinite_seen = self.sim.nonfinite_inputs
            self.get_logger().warning(f"non-finite force commands ignored (total "
                                      f"{self._nonfinite_seen})", throttle_duration_sec=2.0)
        if self.total_steps and self.sim.k >= self.total_steps:
            self._done()

    def _pump(self, max_steps: int = 50) -> None:
        """Lockstep: publish samples until one needs replies (bounded, to stay responsive)."""
        for _ in range(max_steps):
            if self.finished or self._waiting:
                return
            self._publish_sample()
            self._got = {}
            if any(c not in self._absent for c in self.controllers):
                self._waiting = True
                self._t_sent = self._t_retx = time.monotonic()
                return
            self._complete()

    def _complete(self) -> None:
        self._waiting = False
        self._advance({c: self._got.get(c, self._zero) for c in self.controllers})

    def _on_force(self, cid: str, buf: bytes, rx_ns: int | None = None) -> None:
        """A force command (serialized); ``rx_ns``: its arrival (monotonic ns) when taken
        later (drained)."""
        stamp, w = read_stamped(buf, WrenchStamped, self.dof)
        w = self.force_guard.clean(w, 0.0)
        if cid == topics.EXCITATION_ID and self._exc_stage is None:
            self._exc_stage = self._stage_of(read_frame(buf, WrenchStamped))
        now_ns = time.monotonic_ns() if rx_ns is None else rx_ns
        if self.timing_file:  # sensor-to-force latency: sample publication -> force arrival
            k = round(stamp * self.rate / 1e9)
            if 0 <= k < len(self._t_pub):
                self._lat[cid].append(now_ns - self._t_pub[k])
        if not self.lockstep:
            self._held[cid] = (w, now_ns * 1e-9)
            return
        if cid in self._absent:
            self._absent.discard(cid)
            self.get_logger().info(f"{cid} is back")
        if not self._waiting or stamp != self._ns or cid in self._got:
            return  # a repeated or late reply: the first one for a sample counts
        self._got[cid] = w
        self._consec[cid] = 0
        if all(c in self._got or c in self._absent for c in self.controllers):
            self._complete()
            self._pump()

    def _stage_of(self, frame: str) -> int | None:
        """0-based index of the stage an excitation's frame_id names (None: not a stage; the
        excitation then adds nothing, and it is logged)."""
        if frame in self.bodies[1:]:
            return self.bodies.index(frame) - 1
        self.get_logger().error(f"excitation frame_id {frame!r} is not a stage "
                                f"({', '.join(self.bodies[1:])}): ignored",
                                throttle_duration_sec=5.0)
        return None

    def _lockstep_timeout(self) -> None:
        missing = [c for c in self.controllers if c not in self._got and c not in self._absent]
        for c in missing:
            self.faults[c] += 1
            self._consec[c] += 1
            if self._consec[c] >= self.absent_after:
                self._absent.add(c)
                self.get_logger().error(f"{c} missed {self._consec[c]} samples in a row: "
                                        f"absent, not waited for until it publishes again")
        self.get_logger().warning(
            f"no force from {', '.join(missing)} for t={self._ns / 1e9:.4f} s within "
            f"{self.lockstep_timeout_s:g} s: zero force (faults {self.faults})",
            throttle_duration_sec=2.0)
        self._complete()
        self._pump()

    def _realtime(self, now: float) -> None:
        due = int((now - self._t0) * self.rate) + 1 - self.sim.k
        if due > MAX_BURST:
            # too far behind to catch up without a burst: drop the backlog, count it
            self.overruns += due - 1
            self._t0 += (due - 1) / self.rate
            due = 1
        for _ in range(max(due, 0)):
            self._publish_sample()
            wrenches = {}
            for c in self.controllers:
                w, t = self._held.get(c, (self._zero, -math.inf))
                stale = now - t > self.input_timeout_s
                if stale and not self._stale[c]:
                    self.stale_events[c] += 1
                    self.stale_at[c] = (time.monotonic_ns(), self.sim.k)
                    self.get_logger().warning(f"force of {c} is stale (> "
                                              f"{self.input_timeout_s:g} s): zero",
                                              throttle_duration_sec=2.0)
                self._stale[c] = stale
                wrenches[c] = self._zero if stale else w
            self._advance(wrenches)
            if self.finished:
                return

    def _done(self) -> None:
        self._flush_applied()
        wall = time.monotonic() - self._t_run
        self._cpu[1] = time.process_time()
        dropped = f", {self.overruns} dropped as overruns" if self.overruns else ""
        self.get_logger().info(f"finished {self.sim.k} samples ({self.sim.t:.3f} s simulated) "
                               f"in {wall:.2f} s wall: {self.sim.k / max(wall, 1e-9):.0f} "
                               f"samples/s{dropped}")
        self.finish()
        self._report()  # says finished=True: `dcsms up` tells a finished run from a crash

    # -- reporting ---------------------------------------------------------------------------
    def controller_state(self, c: str) -> str:
        """``ok``, ``absent`` (lockstep) or ``stale`` (real time) for one controller."""
        if self.lockstep:
            return "absent" if c in self._absent else "ok"
        return "stale" if self._stale[c] else "ok"

    def _report(self) -> None:
        k0, t0 = self._rate_mark
        now = time.monotonic()
        if self.started and now > t0:
            self.achieved_hz = (self.sim.k - k0) / (now - t0)
            self._rate_mark = (self.sim.k, now)
        states = {c: self.controller_state(c) for c in self.controllers}
        bad = [c for c, s in states.items() if s != "ok"]
        level = DiagnosticStatus.WARN if bad and self.started else DiagnosticStatus.OK
        msg = ("degraded: " + ", ".join(f"{c} {states[c]}" for c in bad) if bad and
               self.started else "running" if self.started else "waiting for the graph")
        values = {"schedule": self.schedule, "sample": self.sim.k,
                  "sim_time_s": f"{self.sim.t:.6f}",
                  "achieved_rate_hz": f"{self.achieved_hz:.1f}", "rate_hz": f"{self.rate:g}",
                  "lockstep_timeouts": sum(self.faults.values()),
                  "retransmits": self.retransmits, "stale_events": sum(self.stale_events.values()),
                  "overruns": self.overruns, "nonfinite_inputs": self.sim.nonfinite_inputs,
                  "rejected_inputs": self.force_guard.rejected,
                  "saturations": self.sim.saturations, "finished": self.finished}
        arr = DiagnosticArray()
        arr.header.stamp = to_stamp(self._ns)
        arr.status = [status("plant_simulator", level, msg, values)] + [
            status(f"plant_simulator/{c}", DiagnosticStatus.OK if s == "ok" else
                   DiagnosticStatus.WARN, s, {"timeouts": self.faults[c],
                                              "stale_events": self.stale_events[c],
                                              "stale_at_mono_ns": self.stale_at[c][0],
                                              "stale_at_sample": self.stale_at[c][1],
                                              "last_input_mono_ns": int(self._held.get(
                                                  c, (None, 0.0))[1] * 1e9)})
            for c, s in states.items()]
        self.pub_diag.publish(arr)

    def close(self) -> None:
        """Give reliable observers a moment to receive what was published (clean exit)."""
        with self._lock:
            self._flush_applied()
            self._report()  # final counters: a recording can be checked against them
        if self.timing_file:
            np.savez(self.timing_file, t_pub_ns=np.asarray(self._t_pub, dtype=np.int64),
                     cpu_s=np.asarray(self._cpu), rate_hz=self.rate, overruns=self.overruns,
                     **{f"lat_ns_{c}": np.asarray(v, dtype=np.int64)
                        for c, v in self._lat.items()})
        wait_acked([self.pub_raw, self.pub_applied, *self.pub_truth, self.pub_diag])


main = main_for(PlantSimulatorNode)

if __name__ == "__main__":
    main()

