"""Where a hot loop's thread runs: its SCHED_FIFO priority, its CPUs, the core a composed
driver shares with the executor's thread, and the CPUs left for the host's helper processes.

:class:`ThreadPlacement` is the base of :class:`~.hotloop.HotLoop`: the host sets
:attr:`~ThreadPlacement.cpus` and :attr:`~ThreadPlacement.share_core_with` before the loop
starts, and the loop's thread places itself as it starts (:meth:`~ThreadPlacement.prioritize`).
"""

from __future__ import annotations

import os
import sys
import threading

from dcsms_ros.ros.cpulatency import CpuLatencyRequest, hold_from_env

#: Python's GIL switch interval once the composed driver and the executor's thread share one
#: core (:meth:`ThreadPlacement.prioritize`; apart: ``hotloop.GIL_SWITCH_S``). There the
#: executor can hold the GIL only while the driver sleeps, and the woken driver waits one
#: interval before Python asks the holder to let go: 200 us at every sample during an executor
#: burst (the trip judge, every 50 ms). At 50 us, 21 alternating pairs of composed 20 s runs:
#: late samples fewer in 15 (5,317 -> 3,663 in all); samples published > 250 us behind their
#: deadline within the judge's 11 ms window fewer in 17 of 18 (2.0-14x). Not on separate cores
#: (one process per node), where both threads run at once and nothing showed a gain: 50 us had
#: fewer late samples in 3 of 6 pairs. 20 us was no better than 200 us (composed, 4 runs).
#: docs/performance.md, "The GIL switch interval on a shared core".
SHARED_CORE_GIL_SWITCH_S = 5e-5


class ThreadPlacement:
    """The priority and CPUs of a hot loop's thread (:attr:`_thread`, the subclass's)."""

    _thread: threading.Thread | None

    def __init__(self) -> None:
        #: Why a priority or a placement was refused (None: all granted).
        self.rt_warning: str | None = None
        #: Native id of a thread to put on the driver's core under SCHED_FIFO (composed: the
        #: executor's thread; None: no pinning).
        self.share_core_with: int | None = None
        #: The CPUs the thread may run on (set before it starts; empty: the kernel places it).
        self.cpus: frozenset[int] = frozenset()
        self._pinned: frozenset[int] = frozenset()
        #: The core the thread was pinned to (None: not pinned to one).
        self.core: int | None = None
        #: The CPU wake-up latency held while the loop runs under SCHED_FIFO (:mod:`.cpulatency`).
        self.cpu_latency: CpuLatencyRequest | None = None

    def prioritize(self, rt_priority: int) -> str | None:
        """Put the running thread (only it) on :attr:`cpus` (if any), under SCHED_FIFO
        ``rt_priority`` (1-99), and hold the CPU wake-up latency :mod:`.cpulatency` asks for
        while the loop runs; returns a warning when any is refused (no CAP_SYS_NICE, not
        root), else None."""
        thread = self._thread
        if thread is None or thread.native_id is None:
            return None
        if self.cpus:
            self._pin(thread.native_id)
        if not rt_priority:
            return self.rt_warning
        try:
            os.sched_setscheduler(thread.native_id, os.SCHED_FIFO, os.sched_param(rt_priority))
        except (OSError, AttributeError) as exc:
            self.rt_warning = (f"SCHED_FIFO priority {rt_priority} refused ({exc}); "
                               f"default scheduler kept")
            return self.rt_warning
        if self.share_core_with is not None:
            self._share_core(thread.native_id, self.share_core_with)
        if self.cpu_latency is None:
            self.cpu_latency, warning = hold_from_env()
            if warning:
                self._warn(warning)
        return self.rt_warning

    def _warn(self, warning: str) -> None:
        """Add ``warning`` to :attr:`rt_warning` (each refusal is reported, none replaced)."""
        self.rt_warning = f"{self.rt_warning}; {warning}" if self.rt_warning else warning

    def _pin(self, tid: int) -> None:
        if self._pinned == self.cpus:  # the thread's start and the host may both ask
            return
        self._pinned = self.cpus
        try:
            os.sched_setaffinity(tid, self.cpus)
        except OSError as exc:
            self._warn(f"CPUs {sorted(self.cpus)} refused ({exc}); the kernel places the thread")
            return
        if len(self.cpus) == 1:
            self.core = min(self.cpus)

    def shared_core(self) -> int | None:
        """The core this loop's thread shares with :attr:`share_core_with` under SCHED_FIFO:
        the last of :attr:`cpus`, else the last the process may use (None: no thread to share
        it with, or a single core)."""
        if self.share_core_with is None:
            return None
        cores = sorted(self.cpus or os.sched_getaffinity(0))
        return cores[-1] if len(cores) > 1 or self.cpus else None

    def spare_cpus(self, rt_priority: int) -> frozenset[int] | None:
        """The CPUs a helper process of the host (the bag writer) keeps to while the loop
        runs under SCHED_FIFO ``rt_priority``: every one the process may use but
        :meth:`shared_core`. A process woken on that core (by a write of the executor's
        thread: the kernel wakes a task where its waker runs) preempts the executor's thread,
        which may hold the GIL the woken driver waits for: a sample late (docs/performance.md,
        "The bag writer off the driver's core"). None: the kernel places it."""
        core = self.shared_core() if rt_priority else None
        spare = frozenset(os.sched_getaffinity(0)) - {core}
        return spare if core is not None and spare else None

    def _share_core(self, tid: int, other: int) -> None:
        """Pin ``tid`` (this loop's thread) and ``other`` to :meth:`shared_core`."""
        core = self.shared_core()
        if core is None:
            return
        try:
            os.sched_setaffinity(tid, {core})
            os.sched_setaffinity(other, {core})
        except OSError as exc:
            self._warn(f"could not put the executor on the driver's core ({exc})")
            return
        self.core = core
        sys.setswitchinterval(min(sys.getswitchinterval(), SHARED_CORE_GIL_SWITCH_S))


__all__ = ["SHARED_CORE_GIL_SWITCH_S", "ThreadPlacement"]
