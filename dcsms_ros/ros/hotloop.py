"""The hot loop: one thread serving the per-sample subscriptions of hot paths from a minimal
wait set (:mod:`.hotpath` declares them), and the composed process's context that owns one.

After each wake-up the loop takes every queued message of the paths' subscriptions with
``take_message`` and runs its handler under the path's lock, then the paths' ticks; it waits
on a wait set of just those subscriptions and a stop guard condition (as
:func:`rclpy.wait_for_message` does), for at most the shortest time a tick asked for. Only
this thread may run under SCHED_FIFO (:mod:`.placement`), and a process with one lowers
Python's GIL switch interval (:data:`GIL_SWITCH_S`). Composed, the
:class:`DrivenContext`'s :attr:`~DrivenContext.driver` loop serves the paths of every node of
the context and dispatches the in-process bus (:mod:`dcsms_ros.protocols.localbus`) in
publication order until nothing is left.

Composed in real time under SCHED_FIFO, the driver and the executor's thread (the process's
main thread) share one core (:mod:`.placement`, ``share_core_with``; not in lockstep,
where the driver never waits and the executor would starve): the executor then runs only
while the driver waits for its next deadline, and a driver that wakes preempts it at once
and takes the GIL within :data:`SHARED_CORE_GIL_SWITCH_S`. On separate cores both ran Python
at the same time and the driver, needing the GIL, got every other switch interval of it during
each executor burst (the trip judge's 50 ms timer, reports, wait-set rebuilds): 6-7 % of the
samples were late on a 2-core machine, 0.4-0.5 % with the shared core (docs/performance.md,
"GIL hand-offs"). The other cores are left to the DDS threads and the other processes.

``DCSMS_HOT_PATH=0`` in the environment turns the hot path off (:func:`enabled`).
"""

from __future__ import annotations

import contextlib
import gc
import math
import os
import sys
import threading
import time
import traceback
from collections.abc import Callable
from contextlib import ExitStack
from typing import Protocol

from rclpy.context import Context
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.subscription import Subscription

from dcsms_ros.protocols.localbus import LocalBus
from dcsms_ros.ros.laneinput import PROBE_S
from dcsms_ros.ros.lanewait import LanePath, LaneWait
from dcsms_ros.ros.pausemeter import PauseMeter
from dcsms_ros.ros.placement import SHARED_CORE_GIL_SWITCH_S, ThreadPlacement

#: Wake-up of the hot thread when nothing arrives (s): bounds the reaction to a stop request.
IDLE_S = 0.1
#: GIL switch interval (s) of a process with a hot thread. Python's default, 5 ms, lets an
#: executor thread that holds the GIL keep the woken hot thread waiting for up to 5 ms (ten
#: samples at 2 kHz): composed, recorded, 10 s of real time at SCHED_FIFO 50 were 52-61 % late
#: with it and 0 % with 0.2 ms (2 runs each, docs/performance.md).
GIL_SWITCH_S = 2e-4


def settle_heap() -> None:
    """Collect the garbage of the start-up and freeze what survived (:func:`gc.freeze`): the
    imports and the nodes' objects (~10^6) are then left out of every later collection, so a
    full collection during the run scans only what the run allocated. Without it a full
    collection of the composed process took ~49 ms with the GIL held, a hundred samples at
    2 kHz (``bench/gil_probe.py``). The host calls it once its nodes exist, before the loop
    starts."""
    gc.collect()
    gc.freeze()


def enabled() -> bool:
    """Whether the hot path is on (default) or turned off by ``DCSMS_HOT_PATH=0``."""
    return os.environ.get("DCSMS_HOT_PATH", "1") not in ("0", "false", "no", "off")


class Served(LanePath, Protocol):
    """What a :class:`HotLoop` serves (a :class:`~.hotpath.HotPath`)."""

    node: Node
    lazy_tick: bool
    timed_tick: bool

    @property
    def ticking(self) -> bool: ...

    def resolve(self) -> list[Subscription]: ...

    def serve(self) -> int: ...

    def tick(self) -> float | None: ...


class HotLoop(ThreadPlacement):
    """One thread serving the hot paths added to it, in the order they were added.

    After each wake-up it empties every path's subscriptions (composed, in passes with the
    bus until a pass takes nothing: a handler's publication is another node's input), then the
    ticks; it waits on a wait set of all the subscriptions and a guard condition for at most
    the shortest time a tick asked for (on its wake-up pipe alone when it serves no DDS
    subscription: composed, with every topic in-process). Its priority and CPUs:
    :class:`~.placement.ThreadPlacement`. After a wait it knows how late it got to run while
    nothing of its process ran (:attr:`woke_late_s`), which the plant's pacer uses to tell the
    samples the machine made late from the graph's own
    (:attr:`~dcsms_ros.protocols.pacer.Pacer.woke_late`).
    """

    def __init__(self, context: Context, name: str) -> None:
        super().__init__()
        self.context = context
        self.name = name
        self.paths: list[Served] = []
        self._stop = False
        self._thread: threading.Thread | None = None
        self._guard: GuardCondition | None = None
        self.error: BaseException | None = None
        #: Called (on the loop's thread) once it failed: the host wakes its spin loop.
        self.on_error: Callable[[], object] | None = None
        self.wakeups = 0
        #: How long after the time its last wait was to end the thread ran again while no
        #: thread of its process ran (s, :class:`.pausemeter.PauseMeter`; 0 when it woke before
        #: that, or went on without waiting): the OS or the hypervisor did not run it (a pause
        #: charged to the waiting thread as CPU included), or another real-time thread had its
        #: core. A delay while another thread of the process ran (holding the GIL) is left
        #: out: that is the graph's own. Measured only when a path's tick is ``timed``
        #: (:meth:`.hotpath.HotPath.set_tick`), else 0.
        self.woke_late_s = 0.0
        self._subs: list[Subscription] = []
        self._serving: list[Served] = []
        self._prioritized = threading.Event()
        #: set by :meth:`wake`: the next pass runs every tick, lazy ones too
        self._rearm = False
        #: the wait on the paths' lanes (one process per node) and on the wake-up pipe; made
        #: at start
        self._lanes: LaneWait | None = None

    @property
    def native_id(self) -> int | None:
        """The running thread's kernel id (None when not running)."""
        return self._thread.native_id if self._thread is not None else None

    def add(self, path: Served) -> None:
        """Serve ``path`` too (before :meth:`start`)."""
        if self._thread is not None:
            raise RuntimeError(f"{self.name}: cannot add a hot path to a running loop")
        self.paths.append(path)

    def start(self, rt_priority: int = 0) -> None:
        """Start the thread; ``rt_priority`` 1-99 puts it (only it) under SCHED_FIFO."""
        if self._thread is not None or not self.paths:
            return
        resolved = [(p, p.resolve()) for p in self.paths]  # before any thread runs
        self._subs = [s for _, subs in resolved for s in subs]
        # only these have anything to take: composed, most paths' topics are all in process,
        # and a pass over every path took each one's lock for nothing
        self._serving = [p for p, subs in resolved if subs]
        self._lanes = LaneWait(self.paths, len(self._serving),
                               timed=any(p.timed_tick for p in self.paths))
        self._guard = GuardCondition(None, None, context=self.context)
        self.context.on_shutdown(self._on_shutdown)
        sys.setswitchinterval(min(sys.getswitchinterval(), GIL_SWITCH_S))
        self._thread = threading.Thread(target=self._run, args=(rt_priority,), name=self.name,
                                        daemon=True)
        self._thread.start()
        if rt_priority or self.cpus:  # its warnings are read once this returns
            self._prioritized.wait(1.0)

    def wake(self) -> None:
        """Run the ticks now (lazy ones too)."""
        self._rearm = True
        if self._guard is not None and self._subs:
            self._guard.trigger()
        if self._lanes is not None:
            self._lanes.wake()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the thread to end and wait for it (idempotent)."""
        self._stop = True
        if self._lanes is not None:
            self._lanes.wake()
        if self._thread is not None:
            if self._guard is not None:
                with contextlib.suppress(Exception):
                    self._guard.trigger()
            self._thread.join(timeout_s)
            self._thread = None
        if self._guard is not None:
            with contextlib.suppress(Exception):
                self._guard.destroy()
            self._guard = None
        if self.cpu_latency is not None:
            self.cpu_latency.close()
            self.cpu_latency = None
        if self._lanes is not None:
            self._lanes.close()

    def _on_shutdown(self) -> None:
        self._stop = True
        if self._lanes is not None:
            self._lanes.wake()
        if self._guard is not None:
            with contextlib.suppress(Exception):  # the context may be gone already
                self._guard.trigger()

    def _run(self, rt_priority: int) -> None:
        if rt_priority or self.cpus:
            self.prioritize(rt_priority)
        self._prioritized.set()
        try:
            self._loop()
        except BaseException as exc:  # noqa: BLE001 - re-raised by the process's spin loop
            if not self._stop and self.context.ok():
                self.error = exc
                self.paths[0].node.get_logger().error(
                    f"{self.name} failed:\n{traceback.format_exc()}")
                if self.on_error is not None:
                    self.on_error()

    def _loop(self) -> None:
        assert self._guard is not None
        subs = self._subs
        bus = self.context.bus if isinstance(self.context, DrivenContext) else None
        if bus is not None:
            bus.owner = threading.get_ident()
        ws = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, 0, self.context.handle)
        first_node = self.paths[0].node
        paths, serving = self.paths, self._serving
        lazy = [p.lazy_tick for p in paths]
        # when each path's tick is due next (monotonic s): a lazy one's when its wait passed,
        # the others' -1 (every pass); a path without a tick never (no call to learn that)
        first = [-1.0 if p.ticking else math.inf for p in paths]
        dues = list(first)
        monotonic = time.monotonic
        waits = self._lanes  # made by start()
        assert waits is not None
        lanes = waits if waits else None  # the lanes, if any
        meter = waits.meter  # None unless a path's tick is timed
        with ExitStack() as stack:
            for s in subs:
                stack.enter_context(s.handle)
            stack.enter_context(self._guard.handle)
            guard = self._guard.handle
            handles = [s.handle for s in subs]
            timeout = IDLE_S
            while not self._stop:
                self.woke_late_s = 0.0
                if (bus is None or not bus.pending) and not handles:
                    # a wake() from now on is seen by the next wait, and what an earlier one
                    # announced is delivered by the pass below
                    if meter is not None:
                        meter.waiting(timeout)
                    waits.sleep(timeout)
                    self._woke(meter)
                    if self._stop:
                        break
                elif lanes is not None and lanes.wait(timeout):
                    self.wakeups += 1  # the lanes time their wait (their meter is ours)
                    self.woke_late_s = lanes.woke_late_s
                    if self._stop:
                        break
                elif bus is None or not bus.pending:  # else go on delivering at once
                    if lanes is not None:  # no lane writer yet: look for a hello again soon
                        timeout = min(timeout, PROBE_S)
                    ws.clear_entities()
                    for h in handles:
                        ws.add_subscription(h)
                    ws.add_guard_condition(guard)
                    if meter is not None:
                        meter.waiting(timeout)
                    ws.wait(max(int(timeout * 1e9), 0))
                    self._woke(meter)
                    if self._stop:
                        break
                    if subs and not ws.get_ready_entities("subscription") and \
                            subs[0] not in first_node.subscriptions:
                        break  # the node was destroyed without stop(): nothing left to serve
                if bus is None:
                    # one pass (each subscription emptied): a message a handler sends to a
                    # reader of this process makes the next wait return at once
                    for p in serving:
                        p.serve()
                while bus is not None and not self._stop:  # until a pass takes nothing
                    n = 0
                    for p in serving:
                        n += p.serve()
                    n += bus.dispatch()
                    if bus.pending or not n:
                        break  # pending: a bounded round (ticks and the stop flag), then on
                timeout = IDLE_S
                if self._rearm:
                    self._rearm = False
                    dues = list(first)
                now = monotonic()
                for i, p in enumerate(paths):
                    due = dues[i]
                    if now < due:  # a lazy tick not due (its deadline only moved later), or none
                        timeout = min(timeout, due - now)  # (no tick: inf, no change)
                        continue
                    nxt = p.tick()
                    if nxt is not None:
                        timeout = min(timeout, max(nxt, 0.0))
                    if lazy[i]:
                        dues[i] = now + (IDLE_S if nxt is None else max(nxt, 0.0))

    def _woke(self, meter: PauseMeter | None) -> None:
        """A wait returned (``meter``: the loop's, None when it does not time its waits)."""
        self.wakeups += 1
        if meter is not None:
            meter.woke()
            self.woke_late_s = meter.woke_late_s

    def take_paused_s(self) -> float:
        """How long, since the last call, the loop worked (was not in a wait) while nothing
        of its process ran (s; :meth:`.pausemeter.PauseMeter.take_paused_s`); 0 when no path's
        tick is ``timed``. Call it from the loop's thread (a tick)."""
        meter = self._lanes.meter if self._lanes is not None else None
        return meter.take_paused_s() if meter is not None else 0.0


class DrivenContext(Context):
    """An rclpy context whose nodes' hot paths one :class:`HotLoop`, :attr:`driver`, serves
    (composed deployment). The host passes it to :func:`.context.ros_context` and to every
    node it creates, then starts :attr:`driver` once the nodes exist and stops it before they
    are destroyed.

    Parameters
    ----------
    name : str
        Name of the driver thread.
    """

    def __init__(self, name: str = "driver") -> None:
        super().__init__()
        self.driver = HotLoop(self, name)
        # the host's executor spins in the thread that creates the context (the main thread)
        self.driver.share_core_with = threading.current_thread().native_id
        #: In-process delivery between the nodes (None with the hot path off).
        self.bus: LocalBus | None = LocalBus(wake=self.driver.wake) if enabled() else None


class HostedContext(Context):
    """An rclpy context of one node per process (:func:`.runtime.run`): the node's hot loop
    starts when the host starts it (:func:`.runtime.spin_node`, after what runs beside the
    node, a recorded run's part, observes its publishers), not when the node's constructor
    asks (:attr:`held` until then). Started by the constructor, a controller answered its first
    58 samples before its part observed the force publisher: 1,599 of 1,657 forces in the bag
    (``test_record_signal.py``, lockstep, 1 of 2-3 runs in a slow hour)."""

    def __init__(self) -> None:
        super().__init__()
        #: True until the host starts the loop: a hot path's ``start()`` does nothing then.
        self.held = True


__all__ = ["GIL_SWITCH_S", "IDLE_S", "SHARED_CORE_GIL_SWITCH_S", "DrivenContext",
           "HostedContext", "HotLoop", "Served", "enabled", "settle_heap"]
