"""Plant simulator node: the cascade, its geophones, disturbances and actuators.

Publishes ``/clock``, the raw geophone channels, the true body velocities and the forces the
actuators applied; subscribes to every controller's force command (names relative to the
graph's namespace). Two schedules (parameter ``schedule``):

* ``lockstep`` - sample k is published, and the plant advances to k+1 only when the
  :class:`~dcsms_ros.protocols.barrier.LockstepBarrier` holds every expected controller's force
  stamped k (and, with ``trip_gate``, mode_switch's verdict on a trip checkpoint ending at k:
  ``trip/check`` asks once the forces of k are in, ``trip/checked`` answers). The same
  :class:`~dcsms_ros.core.simulator.PlantSimulator` calls happen in the same order as in
  :func:`dcsms_ros.core.engine.simulate`, so the trajectory is the batch engine's bit for bit
  (with numba, the same operations compiled: :mod:`dcsms_ros.core.compiledplant`).
  Timeouts, *absent* participants and retransmission are the barrier's. ``hold_at_s`` stops the
  plant before a sample until the parameter changes (mode schedules).
* ``realtime`` - the :class:`~dcsms_ros.protocols.pacer.Pacer` steps the plant on the wall
  clock at ``plant.rate_hz`` with the newest force of each controller
  (:class:`~dcsms_ros.protocols.pacer.HeldInputs`: zero once ``control.input_timeout_s`` has
  passed since the publication of the sample the force answers, not since its arrival, so a
  late answer never closes the loop with more delay than that; see :meth:`PlantIO.arrived`).

Startup handshake (:mod:`.plant_simulator_io`): sample 0 is published only once the graph is
connected, or after ``handshake_timeout_s``.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from dcsms_ros.cdr import WRENCH_STAMPED, read_frame, read_header, read_stamped_floats
from dcsms_ros.core import topics
from dcsms_ros.core.compiledplant import plant_simulator
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import ControllerId
from dcsms_ros.core.trip import check_samples
from dcsms_ros.nodes import plant_simulator_io as plant_io
from dcsms_ros.nodes import recorder_part
from dcsms_ros.nodes.plant_simulator_options import declare_plant_options, replayed_ground
from dcsms_ros.protocols.barrier import Action, LockstepBarrier
from dcsms_ros.protocols.pacer import HeldInputs, Pacer
from dcsms_ros.ros import qos
from dcsms_ros.ros.clock import steady_timer
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.guard import FORCE_LIMIT_FACTOR, InputGuard
from dcsms_ros.ros.heard import HeardEcho
from dcsms_ros.ros.hosted import Hosted
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.intraprocess import SamplePublisher
from dcsms_ros.ros.params import SELECTORS, NodeConfig, add_post_set, declare_schedule
from dcsms_ros.ros.runtime import main_for

#: Barrier participant of the trip checkpoints (mode_switch's verdicts).
TRIP = "trip"


class PlantSimulatorNode(GraphNode, Hosted):
    """ROS adapter around :class:`~dcsms_ros.core.simulator.PlantSimulator`."""

    hot: HotPath  # every instance has one (Hosted declares it optional)

    def __init__(self, node_name: str = topics.PLANT_ID, **kwargs: Any) -> None:
        kwargs.setdefault("namespace", topics.NAMESPACE)
        super().__init__(node_name, **kwargs)
        self.params = NodeConfig(self, SELECTORS["plant_simulator"], self._on_change)
        cfg = self.params.cfg
        self.schedule = declare_schedule(self)
        self.lockstep = self.schedule == "lockstep"
        self.opts = opts = declare_plant_options(self, cfg.plant.num_stages)
        # the excitation node answers each sample like a controller (excitation.py); the
        # plant adds its wrench after the controllers' (as the batch engine's excite=)
        self.controllers = list(opts.controllers) + ([topics.EXCITATION_ID]
                                                     if opts.excitation else [])
        self.sim = plant_simulator(cfg, ground=replayed_ground(opts.ground_from, cfg))
        self.force_guard = InputGuard(self, "force command", FORCE_LIMIT_FACTOR * max(
            a.limit for a in self.sim.allocators))
        self.dof, self.rate = cfg.plant.dof, cfg.plant.rate_hz
        self.total_steps = int(round(opts.duration_s * self.rate)) if opts.duration_s else 0
        gate = self.lockstep and opts.trip_gate
        self.barrier = LockstepBarrier(
            self.controllers + ([TRIP] if gate else []), cfg.control.lockstep_timeout_s,
            opts.retry_s, opts.absent_after, opts.handshake_timeout_s,
            every={TRIP: check_samples(self.rate)}, last=[TRIP])
        self._set_hold(opts.hold_at_s)
        self._zero = np.zeros(self.dof)
        self.pacer = Pacer(self.rate)
        self.held = HeldInputs(self.controllers, cfg.control.input_timeout_s, self._zero)
        # real time: a (re)started controller fades in once it hears that its forces arrive
        self.heard = None if self.lockstep else HeardEcho(
            self, [c for c in self.controllers if ControllerId.is_valid(c)])
        # forces are taken by the hot loop (hotpath.py); the executor keeps handshake,
        # lockstep timeouts/retransmissions and reports, under the same lock
        self.hot = HotPath(self)
        self.io = plant_io.PlantIO(self, self.sim, gate)
        # real time: the forces are held values, so the hot thread does not wake for each one:
        # it drains them at every sample (arrival times from the DDS reception stamps)
        self._drained = not self.lockstep and self.hot.on
        sub_qos = qos.stream_sub(self.lockstep)
        self._force_subs = []
        for cid in self.controllers:
            topic = topics.LOCAL.force(cid)
            if self._drained:
                sub = self.hot.detached(WrenchStamped, topic, sub_qos, raw=True)
                self._force_subs.append((self.hot.drainer(sub), partial(self._on_force, cid)))
            else:
                self.hot.subscribe(WrenchStamped, topic, partial(self._on_force, cid),
                                   sub_qos, raw=True)
        if gate:
            self.hot.subscribe(Header, topics.LOCAL.trip_checked, self._on_checked,
                               qos.stream_sub(True), raw=True)
        add_post_set(self, self._on_local)  # under the hot loop's lock, like every callback
        self.started = False
        self._waiting_hold = False
        # the executor's timer runs the handshake; then the hot loop steps (real time) or
        # pumps and watches the barrier's deadlines (lockstep), unless the hot path is off
        tick = 1.0 / self.rate if not self.lockstep and not self.hot.on else 0.005
        self._tick_timer = steady_timer(self, tick, self._tick)
        # in real time the pacer reads the pauses; lockstep has no deadlines to miss
        self.hot.set_tick(self._hot_tick, timed=not self.lockstep)
        self.housekeeping(opts.status_period_s, self.io.report)
        self.get_logger().info(
            f"{self.schedule} at {self.rate:g} Hz, {cfg.plant.num_stages} stages "
            f"({cfg.plant.fidelity}), controllers {self.controllers}"
            f"{', trip checkpoints' if gate else ''}, {len(self.sim.channels)} channels, "
            f"{self.sim.num_actuators} actuators, seed {cfg.disturbance.seed}")
        self.hot.start()

    # -- parameters ------------------------------------------------------------------------
    def _on_change(self, cfg: SystemConfig, changed: set[str]) -> None:
        # only timeouts are mutable here: the plant and its disturbances are fixed at start
        self.barrier.timeout_s = cfg.control.lockstep_timeout_s
        self.held.timeout_s = cfg.control.input_timeout_s
        self.io.keep_answers_for(cfg.control.input_timeout_s)

    def _set_hold(self, hold_at_s: float) -> None:
        self.barrier.hold = int(round(hold_at_s * self.rate)) if hold_at_s > 0 else None

    def _on_local(self, params: list[Parameter]) -> None:
        for p in params:
            if p.name == "hold_at_s":
                self._set_hold(float(p.value))
                self._waiting_hold = False
                if self.hot.on:
                    self.hot.wake()  # the hot loop pumps on
                else:
                    self._tick()

    # -- stepping ----------------------------------------------------------------------------
    def _tick(self) -> None:
        now = time.monotonic()
        if self.finished:
            return
        if not self.started:
            if not self.io.handshake(now):
                return
            self.started = True
            if self.hot.on:
                # the hot loop steps from here on; its first step starts the schedule
                self._tick_timer.cancel()
                self.hot.wake()
                return
        if not self.lockstep:
            self._realtime(now)
        else:
            self._lockstep(now)

    def _hot_tick(self) -> float | None:
        """On the hot loop after every wake-up: real time steps what is due, lockstep pumps
        and watches the barrier; returns the seconds until the next deadline."""
        if not self.started or self.finished:
            return None
        if self.lockstep:
            return self._lockstep(time.monotonic())
        for drain, on_force in self._force_subs:
            drain(on_force)
        now = time.monotonic()
        # the pauses are read once a sample (a read of the CPU clock), not at every wake-up
        paused = self.hot.take_paused_s() if self.pacer.wait_s(now, self.sim.k) <= 0.0 else 0.0
        self._realtime(now, self.hot.woke_late_s, paused)
        return self.pacer.wait_s(time.monotonic(), self.sim.k)

    def _lockstep(self, now: float) -> float | None:
        """Publish the next samples, or republish / give up on missing answers; returns the
        seconds until the barrier's next deadline (None: nothing to watch)."""
        if not self.barrier.waiting:
            self._pump()
            return None if not self.barrier.waiting else self.barrier.next_deadline(now)
        act = self.barrier.poll(now)
        if act is Action.RETRANSMIT:
            self.io.republish(TRIP in self.barrier.missing() and TRIP in self.barrier.asked)
        elif act is Action.TIMEOUT:
            missing, absent = self.barrier.expire()
            self.io.missed(missing, absent, self.barrier)
            if self.barrier.waiting:
                self._ask()
            else:
                self._complete()
                self._pump()
        return self.barrier.next_deadline(now) if self.barrier.waiting else None

    def _pump(self, max_steps: int = 50) -> None:
        """Lockstep: publish samples until one needs answers (bounded, to stay responsive)."""
        for _ in range(max_steps):
            if self.finished or self.barrier.waiting:
                return
            if not self.barrier.may_publish(self.sim.k):
                if not self._waiting_hold:  # tell the supervisor at once: it switches now
                    self._waiting_hold = True
                    self.io.holding(self.sim.k)
                    self.io.report()
                return
            ns = self.io.publish_sample(self.sim.k)
            if self.barrier.begin(self.sim.k, ns, time.monotonic()):
                self._ask()
                return
            self._complete()

    def _ask(self) -> None:
        """Ask for the trip verdict once the controllers answered the checkpoint sample: a
        trip disables them, which must not reach one before it answered that sample."""
        if TRIP in self.barrier.to_ask():
            self.io.ask_trip(self.barrier.stamp_ns)

    def _complete(self) -> None:
        b = self.barrier
        self._advance({c: b.got.get(c, self._zero) for c in self.controllers})

    def _advance(self, wrenches: dict[str, np.ndarray]) -> None:
        self.io.advance(wrenches, lockstep=self.lockstep)
        if self.total_steps and self.sim.k >= self.total_steps:
            self.io.done()
            self.finish()
            self.io.report()  # says finished=True: `dcsms up` tells a finished run from a crash

    def _on_force(self, cid: str, buf: bytes, wall_ns: int | None = None) -> None:
        """A force command (serialized); ``wall_ns``: its arrival (system clock, ns: its DDS
        reception, or its publication on a lane) when taken later (drained, real time)."""
        # Python floats to the simulator's rows, no array a force (as a controller's sample:
        # in a woken thread the parts cost ~4x their back-to-back price, relay_floor.py)
        stamp, w = read_stamped_floats(buf, WRENCH_STAMPED, self.dof)
        w = self.force_guard.clean_floats(w, 0.0)
        if cid == topics.EXCITATION_ID and self.io.exc_stage is None:
            self.io.excitation_frame(read_frame(buf, WRENCH_STAMPED))
        valid_ns = self.io.arrived(cid, stamp, wall_ns)
        if not self.lockstep:
            self.held.put(cid, w, valid_ns * 1e-9)
            heard = self.heard
            if heard is not None and heard.pending:
                heard.took(cid)
            return
        if cid in self.barrier.absent:
            self.get_logger().info(f"{cid} is back")
        if self.barrier.offer(cid, stamp, w):
            self._complete()
            self._pump()
        else:
            self._ask()

    def _on_checked(self, buf: bytes) -> None:
        """mode_switch judged the trip checkpoint ending at ``stamp``."""
        stamp, _ = read_header(buf)
        if TRIP in self.barrier.absent:
            self.get_logger().info("mode_switch's trip checkpoints are back")
        if self.barrier.offer(TRIP, stamp):
            self._complete()
            self._pump()

    def _realtime(self, now: float, woke_late_s: float = 0.0, paused_s: float = 0.0) -> None:
        for _ in range(self.pacer.due(now, self.sim.k, woke_late_s, paused_s)):
            k = self.sim.k
            self.io.publish_sample(k)
            # forces are aged at sample k's publication, on the clock of the times they count
            # from (a burst's wake-up, ``now``, is older than its later samples: a preempted
            # burst then took old answers as fresh); the force of sample k - 1 is the newest
            # that can be here, older is delayed
            wrenches, newly = self.held.take(self.io.published_s(k), self.io.published_s(k - 1))
            for c in newly:
                self.io.went_stale(c)
            self._advance(wrenches)
            if self.finished:
                return

    def controller_state(self, c: str) -> str:
        """``ok``, ``absent`` (lockstep) or ``stale`` (real time) for one controller."""
        if self.lockstep:
            return self.barrier.state(c)
        return "stale" if self.held.stale[c] else "ok"

    @property
    def faults(self) -> dict[str, int]:
        """Lockstep timeouts per controller."""
        return {c: self.barrier.faults[c] for c in self.controllers}

    def final_reports(self) -> list[SamplePublisher]:
        """Publish what is held back and the final counters; returns the publishers whose
        readers should acknowledge before the node goes (a clean exit loses nothing)."""
        self.io.flush_applied()  # the host holds the hot loop's lock (runtime.close_nodes)
        self.io.report()
        return self.io.closing()


main = main_for(PlantSimulatorNode, attach=recorder_part.attach)

if __name__ == "__main__":
    main()
