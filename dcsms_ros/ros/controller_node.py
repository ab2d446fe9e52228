"""Shared adapter of the feedback and feedforward controller nodes.

One sample: ``velocity/<body>`` (TwistStamped) -> ``loop.step`` -> ``force/<id>``
(WrenchStamped, frame_id = the stage the actuators push, stamp = the input's stamp), both as
serialized CDR (:mod:`dcsms_ros.cdr`), names relative to the graph's namespace. The node
publishes for every sample, zero while disabled, because the lockstep plant waits for every
controller. A repeated stamp (lockstep retransmission) is answered from the cache, an older one
is dropped (:class:`~dcsms_ros.protocols.responder.Answerer`). ``~/enable``
(std_srvs/SetBool) fades the loop in or out over ``control.fade_time_s``; parameter ``enabled``
starts it at full gain in lockstep, as the batch engine starts the controllers of its initial
mode, and fades it in from zero in real time (a restarted controller rejoins a running plant
without a kick): the loop starts, primed, only once the plant has taken one of this process's
forces (zero force until then; :mod:`.heard`), or, with another actuator node as
``force_reader``, once that node's reader matched the force publisher. A tuning change the
model calls unstable in the active mode is rejected (:mod:`.stability`).

Real time only: a :class:`~dcsms_ros.protocols.pacer.Watchdog` publishes zero force while no
input arrived for ``control.input_timeout_s`` (steady wall clock; on the hot thread, whose wait
ends at the deadline, else a timer). With another actuator node than the simulated plant
(``force_reader``: a rig's driver), an input that comes more than that later than the
fastest recent delivery is answered with zero force (:mod:`~dcsms_ros.protocols.inputage`:
a stalled or starved path must not drive a rig's actuators with old velocities; the plant
ages every force itself). In lockstep the plant's own timeout covers a silent input.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rclpy.logging import LoggingSeverity
from std_msgs.msg import Int64
from std_srvs.srv import SetBool

from dcsms_ros.cdr import TWIST_STAMPED, WRENCH_STAMPED, StampedWriter, read_stamped_floats
from dcsms_ros.core import topics
from dcsms_ros.core.compiledcontrol import controller
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import retuned
from dcsms_ros.core.modes import ControllerId
from dcsms_ros.errors import ConfigError
from dcsms_ros.protocols.gate import MATCH_TIMEOUT_S
from dcsms_ros.protocols.inputage import InputAge
from dcsms_ros.protocols.pacer import Watchdog
from dcsms_ros.protocols.responder import skip_free_ns, skipped
from dcsms_ros.ros import qos
from dcsms_ros.ros.clock import steady_timer
from dcsms_ros.ros.connectivity import has_reader, writer_matched
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.guard import MAX_VELOCITY_MPS, InputGuard
from dcsms_ros.ros.heard import HeardBy
from dcsms_ros.ros.hosted import Hosted
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.intraprocess import SamplePublisher
from dcsms_ros.ros.logthrottle import Throttled
from dcsms_ros.ros.params import (
    NodeConfig,
    answerer,
    declare_local,
    declare_observed,
    declare_schedule,
)
from dcsms_ros.ros.readiness import ReadyAnnouncer
from dcsms_ros.ros.reports import Reports, Status
from dcsms_ros.ros.stability import StabilityGuard


class ControllerNode(GraphNode, Hosted):
    """Base of :class:`FeedbackControllerNode` and :class:`FeedforwardControllerNode`."""

    hot: HotPath  # every instance has one (Hosted declares it optional)

    def setup(self, cid: str, select: Callable[[str], bool], body: str) -> None:
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
                              f"service is {topics.LOCAL.enable(cid)}")
        self.cid = cid
        # the hot thread runs _on_velocity; executor callbacks touching the loop take the lock
        self._lock = threading.RLock()
        self.hot = HotPath(self, self._lock)
        self.params = NodeConfig(self, select, self._on_change_locked)
        self.guard_stable = StabilityGuard(self, listen=True)
        self.params.vet = self.guard_stable.vet
        self.lockstep = declare_schedule(self) == "lockstep"
        # the actuator side: the plant in simulation, the rig's actuator driver on hardware
        self.force_reader = declare_local(self, "force_reader", topics.PLANT_ID, "Real time: the "
                                          "actuator node; the plant (default) says when it "
                                          "took a force, another node's reader of the force "
                                          "topic must be matched before the loop starts "
                                          "(empty: any reader), and an input that comes "
                                          "control.input_timeout_s later than the fastest "
                                          "delivery gets zero force")
        enabled = declare_local(self, "enabled", False, "Start enabled at full gain (no fade), "
                                "as the batch engine starts its initial mode")
        self.observed = declare_observed(self)
        cfg = self.params.cfg
        # lockstep starts at full gain, as the batch engine does; real time fades in from zero,
        # so a (re)started controller joins a running plant without a kick
        # compiled where numba is loaded anyway and every us is the one driver thread's
        self.loop = controller(cfg, cid, enabled=bool(enabled) and self.lockstep,
                               compiled=self.hot.bus is not None)
        if enabled and not self.lockstep:
            self.loop.enable(True)
        self.dof, self.rate = cfg.plant.dof, cfg.plant.rate_hz
        self._gap_ns = skip_free_ns(self.rate)
        self.guard = InputGuard(self, f"{cid} velocity", MAX_VELOCITY_MPS)
        self.writer = StampedWriter(WRENCH_STAMPED, ControllerId.parse(cid).frame, self.dof)
        self.watchdog = Watchdog(cfg.control.input_timeout_s)
        self.pub = self.hot.publisher(WrenchStamped, topics.LOCAL.force(cid),
                                      qos.stream_pub(self.lockstep))
        self.reports = Reports(self, self.hot)
        self.hot.subscribe(TwistStamped, topics.LOCAL.velocity(body), self._on_velocity,
                           qos.stream_sub(self.lockstep), raw=True)
        self.create_service(SetBool, "~/enable", self._on_enable)
        self._zero = [0.0] * self.dof
        # lockstep: the first sample is answered (the loop stepped) only once the output
        # reaches every reader; the plant retransmits it meanwhile
        self.answers = answerer(self, self.pub.publish, self.lockstep, [self.pub],
                                self.observed)
        self.samples = self.nonfinite_out = 0
        self.stale_at_mono_ns = 0
        self.changed_at_ns = -1
        self._seen = (0, 0)
        log = self.get_logger()
        # hot-path log lines: decided before rclpy's 250 us caller lookup (ros/logthrottle.py)
        self._log_back = Throttled(log, 2.0, LoggingSeverity.INFO)
        self._log_seen = Throttled(log, 2.0)
        self._log_stale = Throttled(log, 2.0)
        self._log_old = Throttled(log, 2.0)
        self.boot_ns = time.time_ns()  # tells mode_switch a restarted process from the old one
        self.pub_boot = self.create_publisher(Int64, topics.LOCAL.boot(cid), qos.latched())
        self.pub_boot.publish(Int64(data=self.boot_ns))
        # real time: the plant echoes this boot once it took a force of this process
        self.heard = (HeardBy(self, cid, self.boot_ns)
                      if not self.lockstep and self.force_reader == topics.PLANT_ID else None)
        # real time against a rig's actuator driver: inputs that come late get zero force
        self.age = (InputAge(cfg.control.input_timeout_s)
                    if not self.lockstep and self.force_reader != topics.PLANT_ID else None)
        # real time: the loop is stepped (its fade runs) only once its output reaches the plant
        self._linked = self.lockstep
        self._link_check_ns = -1
        self._plant_seen: float | None = None
        if not self.lockstep and self.hot.on:
            # on the hot thread: its wait times out at the deadline, so a silent input is
            # caught on time without waking the executor at 400 Hz (~6 % of a core)
            self.hot.set_tick(self._watchdog_tick, lazy=True)
        elif not self.lockstep:
            steady_timer(self, max(self.watchdog.timeout_s / 4.0, 1e-3), self._watchdog_locked)
        self.housekeeping(1.0, self._report)
        # real time: the plant starts once DDS matched this node's ends (lockstep retransmits)
        self.ready = (None if self.lockstep else
                      ReadyAnnouncer(self, self.hot, cid, self.observed))
        self.get_logger().info(f"{cid}: input {topics.LOCAL.velocity(body)}, output "
                               f"{topics.LOCAL.force(cid)}, "
                               f"{'enabled' if enabled else 'disabled'}")
        self.hot.start()
        self._report()  # at once: mode_switch learns of a restart before the loop starts

    # -- the loop ----------------------------------------------------------------------------
    def _on_velocity(self, buf: bytes) -> None:
        # on Python floats from message to message: in a thread woken every 500 us a
        # sample's parts cost ~4x their back-to-back price, numpy's calls among them
        # (bench/relay_floor.py --answer; -10.6 % CPU a sample, docs/performance.md)
        ns, x = read_stamped_floats(buf, TWIST_STAMPED, self.dof)
        # implausible (non-finite, > 10 m/s): counted and logged here, NaN for the loop, which
        # answers it with zero force (lockstep goes on) and leaves its filters untouched
        x = self.guard.clean_floats(x, math.nan)
        if not self.answers.due(ns):
            return
        last = self.answers.last_ns
        # not called for the usual gap, where it is 0
        if ns - last > self._gap_ns and not self.lockstep and last >= 0 and self._linked:
            # real time drops samples under load (keep-last 1): the fade follows the stamps,
            # so a switch or a trip fades in control.fade_time_s of plant time, not messages;
            # a fade-in skips at most an input timeout: a longer gap (a stall, or the old first
            # sample a just started node may take) must not become a step of the gain
            cap = round(self.watchdog.timeout_s * self.rate) if self.loop.enabled else 100_000
            for _ in range(skipped(last, ns, self.rate, cap)):
                self.loop.fader.step()
        # real time only: in lockstep the plant's own timeout covers a silent input, and the
        # loop is linked from the start
        now_ns = -1
        if not self.lockstep:
            now_ns = time.monotonic_ns()
            if self.watchdog.feed(now_ns * 1e-9):
                self._log_back(lambda: f"{self.cid}: input is back")
            if not self._linked and self._reaches_actuators(ns):
                self._linked = True
                self.loop.prime(x)  # joining a running plant: no filter start-up transient
        w = self.loop.step_floats(x) if self._linked else self._zero
        if not all(map(math.isfinite, w)):  # a NaN must never reach an actuator
            self.nonfinite_out += 1
            w = self._zero
        age = self.age
        if age is not None and not age.fresh(ns, now_ns):
            # the loop stepped (its filters follow the input), its force is withheld
            w = self._zero
            self._log_old(lambda: f"{self.cid}: input {age.worst_s * 1e3:.1f} ms (worst) "
                                  f"later than the fastest delivery, limit "
                                  f"{age.limit_s * 1e3:g} ms: zero force (totals: "
                                  f"{age.old} inputs)")
        self.answers.reply(ns, self.writer.encode(ns, w))
        self.samples += 1
        seen = (self.loop.nonfinite, self.loop.saturations)
        if seen != self._seen:
            what = "non-finite input ignored" if seen[0] != self._seen[0] else \
                "actuator saturation"
            self._log_seen(lambda: f"{self.cid}: {what} (totals: non-finite {seen[0]}, "
                                   f"saturated {seen[1]} samples)")
            self._seen = seen

    def _reaches_actuators(self, ns: int) -> bool:
        """Real time: True once the plant echoed this process's boot (it took one of its
        forces); with another ``force_reader``, once that node's reader and every other reader
        of the force topic this node sees matched the publisher (checked every 10 ms of
        stamps; an incompatible reader holds it MATCH_TIMEOUT_S at most). Before that the
        fade would run unheard: a restarted controller's discovery can take a second, and a
        writer's match does not say that the reader matched it."""
        if self.heard is not None:
            return self.heard.heard
        if ns - self._link_check_ns < 10_000_000 or self.pub.get_subscription_count() == 0:
            return False
        self._link_check_ns = ns
        if self.force_reader and not has_reader(self, self.pub.topic_name, self.force_reader):
            return False
        if self._plant_seen is None:
            self._plant_seen = time.monotonic()
        return (writer_matched(self, self.pub)
                or time.monotonic() - self._plant_seen > MATCH_TIMEOUT_S)

    def _watchdog_tick(self) -> float:
        """Hot-loop tick (lazy: an input only moves the watchdog's deadline later): the
        watchdog when due; seconds until it is due again (before the first input, a timeout:
        its deadline is at least that far)."""
        left = self.watchdog.wait_s(time.monotonic())
        if left is None:
            return self.watchdog.timeout_s
        if left > 0.0:
            return left
        self._watchdog_locked()
        nxt = self.watchdog.wait_s(time.monotonic())
        return self.watchdog.timeout_s if nxt is None else nxt

    def _watchdog_locked(self) -> None:
        with self._lock:
            newly = self.watchdog.check(time.monotonic())
            if newly is None:
                return
            if newly:
                self.stale_at_mono_ns = time.monotonic_ns()  # compared with a kill time
                self._log_stale(lambda: f"{self.cid}: no input for "
                                        f"{self.watchdog.timeout_s:g} s: zero force")
            # stamped with the sample time the plant has reached by now (no /clock needed)
            late = int((time.monotonic() - (self.watchdog.last or 0.0)) * 1e9)
            self.pub.publish(self.writer.encode(max(self.answers.last_ns, 0) + late,
                                                self._zero))

    def _on_enable(self, request: SetBool.Request,
                   response: SetBool.Response) -> SetBool.Response:
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
            self.watchdog.timeout_s = cfg.control.input_timeout_s
            if self.age is not None:
                self.age.limit_s = cfg.control.input_timeout_s
            self.changed_at_ns = self.answers.last_ns  # newest sample before the change
            self.loop = retuned(self.loop, cfg, self.cid,
                                keep_fade="control.fade_time_s" not in changed)
        self.hot.wake()  # a shorter input timeout: the lazy watchdog tick is due sooner

    # -- reporting ---------------------------------------------------------------------------
    def _report(self) -> None:
        stale = self.watchdog.stale
        self.reports.publish(self.answers.last_ns, [Status(
            DiagnosticStatus.WARN if stale else DiagnosticStatus.OK,
            "stale input: zero force" if stale else
            ("enabled" if self.loop.enabled else "disabled"), {
                "enabled": self.loop.enabled, "gain": f"{self.loop.fader.value:.3f}",
                "samples": self.samples, "repeats": self.answers.repeats,
                "out_of_order": self.answers.out_of_order,
                "saturations": self.loop.saturations, "nonfinite_inputs": self.loop.nonfinite,
                "nonfinite_outputs": self.nonfinite_out, "rejected_inputs": self.guard.rejected,
                "stale_at_mono_ns": self.stale_at_mono_ns,
                "last_input_mono_ns": int((self.watchdog.last or 0.0) * 1e9),
                "last_answer_ns": self.answers.last_ns,
                "params_changed_at_ns": self.changed_at_ns,
                "stale_events": self.watchdog.stale_events,
                **self._age_report(),
                "boot_ns": self.boot_ns})])

    def _age_report(self) -> dict[str, object]:
        if self.age is None:
            return {"age_guard": False}
        floor = self.age.floor_ns
        return {"age_guard": True, "old_inputs": self.age.old,
                "last_old_ns": self.age.last_old_ns,
                "worst_excess_ms": f"{self.age.worst_s * 1e3:.3f}",
                "fastest_offset_ns": -1 if floor is None else floor}

    def final_reports(self) -> list[SamplePublisher]:
        """Publish the final counters; returns the publishers whose readers should
        acknowledge before the node goes (a clean exit loses nothing)."""
        self._report()
        return [self.pub, self.reports.pub]
