"""How long a real-time loop lost while no thread of its process ran: the machine's share of
its late samples (the plant's pacer counts them apart, :class:`~dcsms_ros.protocols.pacer.Pacer`).
"""

from __future__ import annotations

import time

_PROCESS_CPU = time.CLOCK_PROCESS_CPUTIME_ID


def process_cpu_ns() -> int:
    """CPU time of the whole process, every thread (ns; ~0.7 us a call here)."""
    return time.clock_gettime_ns(_PROCESS_CPU)


class PauseMeter:
    """Where a timed hot loop lost time while no thread of its process ran: after a wait's
    timeout (:attr:`woke_late_s`) and while it worked between waits (:meth:`take_paused_s`).

    Each span's wall time less the CPU time the whole process used meanwhile (every thread) is
    time at least that long no thread of it ran: the OS or the hypervisor did not run it, or
    another real-time thread had its core. The rest of a delay another thread of the process
    may have caused: composed, the executor's thread holding the GIL in a long C call, which
    the woken driver (same core) preempts but cannot run Python before it returns. Measured
    in a composed run, the wake-ups >= 0.3 ms late split cleanly: the process used about the
    whole delay (a GIL hold) or none of it (the machine paused; docs/performance.md, "The
    executor's C calls"). A pause that comes while the loop works (a sample's computation)
    delays it as much as one that comes while it sleeps, and is counted apart. The meter
    reads the process's CPU clock once before and once after each wait (~0.7 us a read here)
    and once at each :meth:`take_paused_s`.
    """

    def __init__(self) -> None:
        #: how long after its timeout the last wait returned with no thread of the process
        #: running (s; 0: before it)
        self.woke_late_s = 0.0
        self._paused_s = 0.0
        self._t, self._cpu = time.monotonic(), process_cpu_ns()
        self._end, self._cpu_wait = 0.0, self._cpu

    def waiting(self, timeout_s: float) -> None:
        """A wait of at most ``timeout_s`` (s) begins: the work since the last wake-up ends."""
        now, cpu = time.monotonic(), process_cpu_ns()
        self._paused_s += _unrun_s(now - self._t, cpu - self._cpu)
        self._end, self._cpu_wait = now + max(timeout_s, 0.0), cpu

    def woke(self) -> None:
        """The wait returned (its timeout, a message or a wake-up)."""
        now, cpu = time.monotonic(), process_cpu_ns()
        self.woke_late_s = _unrun_s(now - self._end, cpu - self._cpu_wait)
        self._t, self._cpu = now, cpu

    def take_paused_s(self) -> float:
        """How long, since the last call, the loop worked (was not in a wait) while no thread
        of its process ran (s); the next call counts from now."""
        now, cpu = time.monotonic(), process_cpu_ns()
        out = self._paused_s + _unrun_s(now - self._t, cpu - self._cpu)
        self._paused_s, self._t, self._cpu = 0.0, now, cpu
        return out


def _unrun_s(wall_s: float, cpu_ns: int) -> float:
    """Of ``wall_s`` (s; none if not positive), the time at least that long no thread of the
    process ran, which used ``cpu_ns`` of CPU meanwhile."""
    return max(wall_s - cpu_ns * 1e-9, 0.0) if wall_s > 0.0 else 0.0

__all__ = ["PauseMeter", "process_cpu_ns"]
