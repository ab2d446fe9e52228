"""The plant node's publications, start-up handshake, diagnostics and benchmark timing.

:class:`PlantIO` owns the plant's publishers and what it reports; the node
(:mod:`.plant_simulator`) owns the stepping and the protocols. Per sample the raw channels go
out first (the control path waits for them), then the previous sample's applied forces, the
clock and the true velocities; observer topics nobody subscribes to are not serialized at all.

Handshake: sample 0 is published only once every force topic has a publisher, the raw topic a
subscriber, in real time the decoupling and every controller announced that DDS matched their
ends (a writer of an observed topic: its reader outside the graph too) and the plant's force
readers matched their writers (:mod:`dcsms_ros.ros.readiness`),
with ``trip_gate`` mode_switch's trip topics are connected, each topic in
``wait_for_subscribers`` has a subscriber outside the graph (a recorder, a test probe, or the
``/diagnostics`` reader of ``dcsms up`` that must hear the run end), and the plant's own
writers matched every reader, then :data:`SETTLE_S` more; or after
``handshake_timeout_s``.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TwistStamped
from rclpy.logging import LoggingSeverity
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Header, Int64

from dcsms_ros.cdr import (
    TWIST_STAMPED,
    JointStateWriter,
    StampedWriter,
    clock_bytes,
    header_bytes,
)
from dcsms_ros.core import topics
from dcsms_ros.core.simulator import PlantSimulator
from dcsms_ros.protocols.barrier import LockstepBarrier
from dcsms_ros.protocols.matched import MatchCount
from dcsms_ros.protocols.pacer import Publications
from dcsms_ros.protocols.runstats import LatencyHistogram
from dcsms_ros.ros import qos
from dcsms_ros.ros.connectivity import (
    End,
    control_path,
    missing_ends,
    outside_graph,
    publishers_matched,
)
from dcsms_ros.ros.intraprocess import SamplePublisher
from dcsms_ros.ros.logthrottle import Throttled
from dcsms_ros.ros.msgs import sample_ns
from dcsms_ros.ros.params import declare_observed
from dcsms_ros.ros.readiness import DECOUPLING, ReadySet
from dcsms_ros.ros.reports import Reports, Status

#: Seconds the handshake waits after the graph looks connected, so DDS endpoints match too.
SETTLE_S = 0.2


class PlantIO:
    """Publishers, handshake, reports and timing of a plant node.

    Parameters
    ----------
    node : PlantSimulatorNode
        The node (its options, barrier, pacer, held inputs and controllers).
    sim : PlantSimulator
        The simulated plant.
    trip_gate : bool
        Lockstep trip checkpoints: publish ``trip/check`` and expect mode_switch.
    """

    def __init__(self, node: Any, sim: PlantSimulator, trip_gate: bool) -> None:
        self.node, self.sim = node, sim
        opts = node.opts
        names = topics.LOCAL
        pub_qos = qos.stream_pub(node.lockstep)
        self.bodies = topics.body_names(sim.cfg.plant.num_stages)
        self.observed = declare_observed(node)
        log = node.get_logger()
        # hot-path log lines: decided before rclpy's 250 us caller lookup (ros/logthrottle.py)
        self._log_frame = Throttled(log, 5.0, LoggingSeverity.ERROR)
        self._log_nonfinite = Throttled(log, 2.0)
        self._log_missed = Throttled(log, 2.0)
        self._log_stale = Throttled(log, 2.0)
        self.pub_clock = node.create_publisher(ClockMsg, topics.CLOCK, qos.clock())
        # /clock is volatile keep-last 1: published only while a reader is matched (asked at
        # most every ms), as a per-sample writer does; a DDS publication nobody takes cost the
        # composed lockstep step ~16 us every 20th sample
        self._clock_readers = MatchCount(self.pub_clock.get_subscription_count)
        # per-sample streams: composed, handed to in-process readers directly (hotpath.py)
        pub = node.hot.publisher
        self.pub_raw = pub(JointState, names.sensors_raw, pub_qos)
        # durable like the velocities: mode_switch's supervisor needs every sample from 0
        self.pub_applied = pub(JointState, names.actuators_applied,
                               qos.stream_pub(node.lockstep, durable=True))
        self.pub_truth = [pub(TwistStamped, names.truth(b), pub_qos)
                          for b in self.bodies] if opts.publish_truth else []
        self.reports = Reports(node, node.hot)
        # what a supervisor decides on travels on typed topics, not in the diagnostics' text
        self.pub_held = node.create_publisher(Int64, names.plant_held, qos.latched())
        self.pub_finished = node.create_publisher(Bool, names.plant_finished, qos.latched())
        self.pub_check = (pub(Header, names.trip_check, qos.stream_pub(True))
                          if trip_gate else None)
        # the per-sample messages are serialized here directly (dcsms_ros.cdr: no message objects)
        self._w_raw = JointStateWriter([c.name for c in sim.channels], "velocity")
        self._w_applied = JointStateWriter(sim.actuator_names, "effort")
        self._w_truth = [StampedWriter(TWIST_STAMPED, b, sim.cfg.plant.dof) for b in self.bodies]
        self.clock_every = max(1, int(round(sim.cfg.plant.rate_hz / opts.clock_rate_hz)))
        self.ns = 0
        self._raw_msg = b""
        self._applied: tuple[np.ndarray, int] | None = None
        self._wall_to_mono = time.monotonic_ns() - time.time_ns()
        self._t_pub: list[int] = []  # timing_file: monotonic ns of each sample's publication
        self._lat: dict[str, list[int]] = {c: [] for c in node.controllers}
        self._pubs = Publications(sim.cfg.plant.rate_hz)
        self.keep_answers_for(sim.cfg.control.input_timeout_s)
        self._timing = bool(opts.timing_file)
        self.latency_hist = LatencyHistogram()
        self._cpu = [0.0, 0.0]
        self._nonfinite_seen = 0
        self.stale_at: dict[str, tuple[int, int]] = dict.fromkeys(node.controllers, (0, 0))
        self._t_start = time.monotonic()
        self._ready_at: float | None = None
        self._t_run = 0.0
        self._rate_mark = (0, self._t_start)
        self.achieved_hz = 0.0
        #: 0-based stage the excitation's frame_id names (None: not known yet, or not a stage)
        self.exc_stage: int | None = None
        #: real time: who announced that DDS matched its ends (lockstep retransmits instead)
        self.ready = None if node.lockstep else ReadySet(node, [DECOUPLING, *node.controllers])

    # -- handshake ---------------------------------------------------------------------------
    def _missing(self) -> list[str]:
        """What the graph still lacks before sample 0 can be published."""
        nd, names = self.node, topics.LOCAL
        ends = control_path(names, nd.controllers)
        if self.pub_check is not None:
            ends += [End(names.trip_checked, True, "mode_switch's trip checkpoints"),
                     End(names.trip_check, False, "mode_switch's trip checkpoints")]
        out = missing_ends(nd, ends)
        out += [f"observer of {t}" for t in self.observed if not outside_graph(nd, t)]
        if self.ready is not None:
            # a reader drops the samples of a writer it has not matched, whatever the writer's
            # own count says: each end of the loop confirms from its side (ros/readiness.py)
            out += [f"{r}'s DDS matches" for r in self.ready.missing()]
            out += [f"the plant's reader of {t}" for t in nd.hot.unmatched(
                [names.force(c) for c in nd.controllers])]
        own = [self.pub_raw, self.pub_applied, *self.pub_truth]
        # a supervisor (`dcsms up`) must hear the end
        own += [p for p in (self.reports.pub, self.pub_finished) if p.topic_name in self.observed]
        if self.pub_check is not None:
            own.append(self.pub_check)
        if not out and not publishers_matched(nd, own, self.observed):
            out.append("DDS matching of the plant's publishers")
        return out

    def handshake(self, now: float) -> bool:
        """True once sample 0 may go out (then the run's clocks start)."""
        missing = self._missing()
        if missing and now - self._t_start < self.node.opts.handshake_timeout_s:
            self._ready_at = None
            return False
        if missing:
            self.node.get_logger().warning(f"starting without: {', '.join(missing)}")
        elif self._ready_at is None:
            self._ready_at = now
            return False
        elif now - self._ready_at < SETTLE_S:
            return False
        self._t_run = now
        self._cpu[0] = time.process_time()
        self._rate_mark = (self.sim.k, now)
        self.node.get_logger().info("graph connected: stepping")
        return True

    # -- publishing --------------------------------------------------------------------------
    def publish_sample(self, k: int) -> int:
        """Publish sample ``k`` (the core calls keep the engine's order); returns its stamp."""
        ns = sample_ns(k, self.sim.cfg.plant.rate_hz)
        self.ns = ns
        t_pub = time.monotonic_ns()
        self._pubs.put(k, t_pub)
        if self._timing:
            self._t_pub.append(t_pub)
        truth = self.sim.truth().tolist()  # rows of floats: no row view or scalar per body
        raw = self.sim.measure()
        self._raw_msg = self._w_raw.encode(ns, raw)
        self.pub_raw.publish(self._raw_msg)
        if self._applied is not None:  # lockstep (real time flushed them in advance())
            self.flush_applied()
        if k % self.clock_every == 0 and self._clock_readers():
            self.pub_clock.publish(clock_bytes(ns))
        for b, (pub, v) in enumerate(zip(self.pub_truth, truth, strict=False)):
            # observed: recorded here (encoded in the part's batch), no call to ask
            if pub.observed or pub.wanted():
                pub.publish_later(self._w_truth[b].encode, ns, v)
        return ns

    def ask_trip(self, ns: int) -> None:
        """Ask mode_switch to judge the trip checkpoint ending at the sample stamped ``ns``."""
        if self.pub_check is not None:
            self.pub_check.publish(header_bytes(ns, "check"))

    def republish(self, trip: bool) -> None:
        """Lockstep retransmission of the current sample (and of the trip question)."""
        self.pub_raw.publish(self._raw_msg)
        if trip:
            self.ask_trip(self.ns)

    def flush_applied(self) -> None:
        """Publish the applied forces held back by :meth:`advance` (lockstep)."""
        if self._applied is not None:
            applied, ns = self._applied
            self._applied = None
            if self.pub_applied.observed or self.pub_applied.wanted():
                self.pub_applied.publish(self._w_applied.encode(ns, applied))

    def excitation_frame(self, frame: str) -> None:
        """Learn the stage of the excitation from its ``frame_id`` (logged if not a stage:
        the excitation then adds nothing)."""
        if frame in self.bodies[1:]:
            self.exc_stage = self.bodies.index(frame) - 1
            return
        self._log_frame(lambda: f"excitation frame_id {frame!r} is not a stage "
                                f"({', '.join(self.bodies[1:])}): ignored")

    def advance(self, wrenches: dict[str, np.ndarray], lockstep: bool) -> None:
        """Step the plant with ``wrenches`` (the excitation's, if any, is added after the
        controllers' as the batch engine does); lockstep publishes the applied forces after the
        next raw sample, off the loop's critical path."""
        exc = None
        if topics.EXCITATION_ID in wrenches:
            w = wrenches.pop(topics.EXCITATION_ID)
            exc = np.zeros((len(self.bodies) - 1, self.sim.dof))
            if self.exc_stage is not None:
                exc[self.exc_stage] = w
        self._applied = (self.sim.advance(wrenches, exc), self.ns)
        if not lockstep:
            self.flush_applied()
        if self.sim.nonfinite_inputs != self._nonfinite_seen:
            self._nonfinite_seen = self.sim.nonfinite_inputs
            self._log_nonfinite(lambda: f"non-finite force commands ignored (total "
                                        f"{self._nonfinite_seen})")

    # -- events ------------------------------------------------------------------------------
    def arrived(self, cid: str, stamp: int, wall_ns: int | None = None) -> int:
        """A force stamped ``stamp`` arrived at ``wall_ns`` (system clock, ns: its DDS
        reception or its publication on a lane; None: now). Records its control latency
        (sample publication -> force arrival) in :attr:`latency_hist`, and per force for
        benchmarks. Returns the monotonic ns the force counts from (real time): the publication
        of the sample it answers, or earlier after a catch-up burst
        (:meth:`.Publications.answered`), so its age is the delay it adds to the loop.
        Table1's stage-2 loop in DFBC+FFC has 93 deg of phase at its 14.6 Hz crossover, 17.7
        ms of delay; one process per node delivered forces up to 59 ms (p99) after their
        sample, and aged from their arrival they were applied: the stages rang up to 19 mm/s
        until the supervisor tripped. An answer to a sample older than the publications kept
        counts as never valid; one stamped ahead of the newest sample published (not an answer
        of this loop) from its arrival. One call a force (three a sample): the latency and the
        time it counts from share the sample's index."""
        now_ns = time.monotonic_ns() if wall_ns is None else wall_ns + self._wall_to_mono
        k = round(stamp * self.sim.cfg.plant.rate_hz / 1e9)
        t_pub, valid_ns = self._pubs.answered(k, now_ns)
        if t_pub is not None:  # older answers: their publication time is gone
            self.latency_hist.add((now_ns - t_pub) * 1e-9)
        if self._timing and 0 <= k < len(self._t_pub):
            self._lat[cid].append(now_ns - self._t_pub[k])
        return valid_ns

    def keep_answers_for(self, timeout_s: float) -> None:
        """Remember the publications an answer up to ``timeout_s`` old (the input timeout,
        s) needs to be aged (:meth:`.Publications.cover`)."""
        self._pubs.cover(timeout_s)

    def published_s(self, k: int) -> float:
        """Monotonic s of sample ``k``'s publication (the unit and value :meth:`arrived`
        gives its answers, in s); -inf before sample 0."""
        t_pub = self._pubs.at_ns(k)
        return -math.inf if t_pub is None else t_pub * 1e-9

    def missed(self, missing: list[str], absent: list[str], barrier: LockstepBarrier) -> None:
        """Log a lockstep timeout."""
        log = self.node.get_logger()
        for c in absent:
            log.error(f"{c} missed {barrier.consec[c]} samples in a row: absent, not waited "
                      f"for until it answers again")
        self._log_missed(lambda: f"no answer from {', '.join(missing)} for t="
                                 f"{self.ns / 1e9:.4f} s within {barrier.timeout_s:g} s: zero "
                                 f"force (faults {barrier.faults})")

    def went_stale(self, c: str) -> None:
        """Real time: the force of ``c`` just went stale (the fault tests read when)."""
        self.stale_at[c] = (time.monotonic_ns(), self.sim.k)
        self._log_stale(lambda: f"force of {c} is stale (> {self.node.held.timeout_s:g} s): "
                                f"zero")

    def holding(self, sample: int) -> None:
        """Lockstep: the plant stopped before ``sample`` (its hold); say so on ``plant/held``."""
        self.pub_held.publish(Int64(data=sample))

    def done(self) -> None:
        """The run's last sample: say so on ``plant/finished`` and log the summary."""
        self.pub_finished.publish(Bool(data=True))
        self.flush_applied()
        wall = time.monotonic() - self._t_run
        self._cpu[1] = time.process_time()
        pacer = self.node.pacer
        dropped = (f", {pacer.late} late, {pacer.overruns} dropped as overruns ("
                   f"{pacer.woke_late} of them while the loop waited to run and nothing of "
                   f"its process ran, {pacer.paused} pushed back by such a pause while it "
                   f"worked)"
                   if pacer.late or pacer.overruns else "")
        self.node.get_logger().info(
            f"finished {self.sim.k} samples ({self.sim.t:.3f} s simulated) in {wall:.2f} s "
            f"wall: {self.sim.k / max(wall, 1e-9):.0f} samples/s{dropped}")

    # -- reporting ---------------------------------------------------------------------------
    def report(self) -> None:
        """Publish the plant's diagnostics (and one status per controller)."""
        nd = self.node
        k0, t0 = self._rate_mark
        now = time.monotonic()
        if nd.started and now > t0:
            self.achieved_hz = (self.sim.k - k0) / (now - t0)
            self._rate_mark = (self.sim.k, now)
        states = {c: nd.controller_state(c) for c in nd.controllers}
        bad = [c for c, s in states.items() if s != "ok"]
        level = DiagnosticStatus.WARN if bad and nd.started else DiagnosticStatus.OK
        msg = ("degraded: " + ", ".join(f"{c} {states[c]}" for c in bad) if bad and
               nd.started else "running" if nd.started else "waiting for the graph")
        b = nd.barrier
        hold = b.hold if b.hold is not None else -1
        values = {"schedule": nd.schedule, "sample": self.sim.k,
                  "sim_time_s": f"{self.sim.t:.6f}", "achieved_rate_hz": f"{self.achieved_hz:.1f}",
                  "rate_hz": f"{self.sim.cfg.plant.rate_hz:g}",
                  "lockstep_timeouts": sum(b.faults.values()), "retransmits": b.retransmits,
                  "stale_events": sum(nd.held.stale_events.values()),
                  "stale_samples": sum(nd.held.stale_samples.values()),
                  "delayed_samples": sum(nd.held.delayed_samples.values()),
                  "controllers": len(nd.controllers),
                  "latency_p50_ms": f"{self.latency_hist.quantile(0.5) * 1e3:.4f}",
                  "latency_p99_ms": f"{self.latency_hist.quantile(0.99) * 1e3:.4f}",
                  "overruns": nd.pacer.overruns, "late_steps": nd.pacer.late,
                  "woke_late_steps": nd.pacer.woke_late, "paused_steps": nd.pacer.paused,
                  "nonfinite_inputs": self.sim.nonfinite_inputs,
                  "rejected_inputs": nd.force_guard.rejected,
                  "saturations": self.sim.saturations, "finished": nd.finished,
                  "hold_sample": hold, "held": hold == self.sim.k and not b.waiting,
                  "trip_checkpoints": b.state("trip") if "trip" in b.participants else "off"}
        self.reports.publish(self.ns, [Status(level, msg, values)] + [
            Status(DiagnosticStatus.OK if s == "ok" else DiagnosticStatus.WARN, s,
                        {"timeouts": b.faults[c], "stale_events": nd.held.stale_events[c],
                         "stale_at_mono_ns": self.stale_at[c][0],
                         "stale_at_sample": self.stale_at[c][1],
                         "last_input_mono_ns": int(max(nd.held.arrived(c), 0.0) * 1e9)}, sub=c)
            for c, s in states.items()])

    def closing(self) -> list[SamplePublisher]:
        """Write the timing file (benchmarks); returns the publishers to wait for."""
        if self.node.opts.timing_file:
            arrays: dict[str, Any] = {
                "t_pub_ns": np.asarray(self._t_pub, dtype=np.int64),
                "cpu_s": np.asarray(self._cpu), "rate_hz": self.sim.cfg.plant.rate_hz,
                "overruns": self.node.pacer.overruns, "late_steps": self.node.pacer.late,
                "woke_late_steps": self.node.pacer.woke_late,
                "paused_steps": self.node.pacer.paused,
                "stale_samples": sum(self.node.held.stale_samples.values())}
            arrays.update({f"lat_ns_{c}": np.asarray(v, dtype=np.int64)
                           for c, v in self._lat.items()})
            np.savez(self.node.opts.timing_file, **arrays)
        return [self.pub_raw, self.pub_applied, *self.pub_truth, self.reports.pub, self.pub_held,
                self.pub_finished]


__all__ = ["SETTLE_S", "PlantIO"]
