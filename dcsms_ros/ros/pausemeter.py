"""How long a real-time loop lost while no thread of its process ran: the machine's share of
its late samples (the plant's pacer counts them apart, :class:`~dcsms_ros.protocols.pacer.Pacer`).
"""

from __future__ import annotations

import time

_PROCESS_CPU = time.CLOCK_PROCESS_CPUTIME_ID
_THREAD_CPU = time.CLOCK_THREAD_CPUTIME_ID


def process_cpu_ns() -> int:
    """CPU time of the whole process, every thread (ns; ~0.6 us a call here)."""
    return time.clock_gettime_ns(_PROCESS_CPU)


class PauseMeter:
    """Where a timed hot loop lost time while no thread of its process ran: after a wait's
    timeout (:attr:`woke_late_s`) and while it worked between waits (:meth:`take_paused_s`).
    Use it from the loop's thread only.

    A span's wall time less the CPU time the process used meanwhile is time no thread of it
    ran: the OS or the hypervisor did not run it, or another real-time thread had its core.
    The rest of a delay another thread of the process may have caused: composed, the
    executor's thread holding the GIL in a long C call, which the woken driver (same core)
    preempts but cannot run Python before it returns. A pause that comes while the loop
    works (a sample's computation) delays it as much as one that comes while it sleeps, and
    is counted apart.

    A pause of the virtual machine that lands while the loop's own thread is on a core is
    charged to that thread as CPU (a thread spinning on the clocks here saw 2.8 ms gaps,
    each charged in full, on an idle machine: ``bench/timer_floor.py --charged``). While it
    works that cannot be told from its work. In a wait the thread does no work: its CPU
    there is its wake-up and its asking for the GIL while another thread holds it, counted
    as the process's up to as much CPU as the other threads used meanwhile; the rest of its
    charge counts as the machine's in :attr:`woke_late_s`. (Asking for the GIL behind a C
    call cost the asker 0.08 of the holder's CPU at the hot loops' 200 us switch interval,
    0.2 at 50 us; in the composed graph's late wake-ups that other threads' CPU covered, the
    driver's charge was 0.35-0.9 of theirs: docs/performance.md, fifty-eighth session.) The
    meter reads the process's and the thread's CPU clocks before and after each wait
    (~0.6 us a read here) and the process's at each :meth:`take_paused_s`.
    """

    def __init__(self) -> None:
        #: how long after its timeout the last wait returned with no thread of the process
        #: running, the time charged to the loop's own thread while it waited counted as not
        #: running (s; 0: before it)
        self.woke_late_s = 0.0
        self._paused_s = 0.0
        self._t, self._cpu = time.monotonic(), process_cpu_ns()
        self._end, self._cpu_wait, self._own_wait = 0.0, self._cpu, 0

    def waiting(self, timeout_s: float) -> None:
        """A wait of at most ``timeout_s`` (s) begins: the work since the last wake-up ends."""
        now, cpu = time.monotonic(), process_cpu_ns()
        self._own_wait = time.clock_gettime_ns(_THREAD_CPU)
        self._paused_s += _unrun_s(now - self._t, cpu - self._cpu)
        self._end, self._cpu_wait = now + max(timeout_s, 0.0), cpu

    def woke(self) -> None:
        """The wait returned (its timeout, a message or a wake-up)."""
        own = time.clock_gettime_ns(_THREAD_CPU) - self._own_wait
        now, cpu = time.monotonic(), process_cpu_ns()
        self.woke_late_s = _unrun_s(now - self._end,
                                    _ran_while_waiting_ns(cpu - self._cpu_wait, own))
        self._t, self._cpu = now, cpu

    def take_paused_s(self) -> float:
        """How long, since the last call, the loop worked (was not in a wait) while no thread
        of its process ran (s); the next call counts from now."""
        now, cpu = time.monotonic(), process_cpu_ns()
        out = self._paused_s + _unrun_s(now - self._t, cpu - self._cpu)
        self._paused_s, self._t, self._cpu = 0.0, now, cpu
        return out


def _ran_while_waiting_ns(process_ns: int, own_ns: int) -> int:
    """Of ``process_ns``, the CPU the process used during a wait of one of its threads, which
    was charged ``own_ns`` of it, the part that was the process's running (ns): the other
    threads' CPU and, up to as much again, the waiter's asking for the GIL they may have held."""
    return min(process_ns, 2 * max(process_ns - own_ns, 0))


def _unrun_s(wall_s: float, cpu_ns: int) -> float:
    """Of ``wall_s`` (s; none if not positive), the time at least that long no thread of the
    process ran, which used ``cpu_ns`` of CPU meanwhile."""
    return max(wall_s - cpu_ns * 1e-9, 0.0) if wall_s > 0.0 else 0.0

__all__ = ["PauseMeter", "process_cpu_ns"]
