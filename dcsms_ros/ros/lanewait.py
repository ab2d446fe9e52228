"""How a hot loop (:mod:`.hotloop`) of one process per node waits on its paths' host lanes.

A loop whose paths read lanes (:mod:`.laneinput`) waits on their FIFOs and on a pipe that
:meth:`LaneWait.wake` writes, instead of DDS, once every served subscription has a lane writer;
while some subscription also has a DDS writer without a lane it waits at most
:data:`DDS_POLL_S` (its DDS messages are taken after each wake-up), and while no lane writer
serves them it does not wait here at all (the loop waits on DDS). That choice is judged from
the paths' lane states; a lanes or mixed wait is kept for :data:`~.laneinput.STATE_S`, a DDS
one is judged again at every wake-up, so a writer's hello moves the loop onto its lane at once
(its messages may come only there).
"""

from __future__ import annotations

import contextlib
import os
import select
import time
from collections.abc import Sequence
from typing import Protocol

from dcsms_ros.ros.laneinput import DDS, LANES, MIXED, STATE_S

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

    def waiting(self, now: float, end: float) -> None:
        """A wait begins at ``now`` (monotonic s) and is to end at ``end``: the work since the
        last wake-up ends."""
        cpu = process_cpu_ns()
        self._paused_s += max(now - self._t - (cpu - self._cpu) * 1e-9, 0.0)
        self._end, self._cpu_wait = end, cpu

    def woke(self) -> None:
        """The wait returned (its timeout, a message or a wake-up)."""
        now, cpu = time.monotonic(), process_cpu_ns()
        late = now - self._end
        self.woke_late_s = max(late - (cpu - self._cpu_wait) * 1e-9, 0.0) if late > 0.0 else 0.0
        self._t, self._cpu = now, cpu

    def take_paused_s(self) -> float:
        """How long, since the last call, the loop worked (was not in a wait) while no thread
        of its process ran (s); the next call counts from now."""
        now, cpu = time.monotonic(), process_cpu_ns()
        out = self._paused_s + max(now - self._t - (cpu - self._cpu) * 1e-9, 0.0)
        self._paused_s, self._t, self._cpu = 0.0, now, cpu
        return out


#: Longest wait (s) on the lanes while a subscription also has a DDS writer without a lane
#: (its DDS messages are taken after each wake-up; rare: another host's or a tool's writer of
#: a topic the graph writes too).
DDS_POLL_S = 0.001


class LanePath(Protocol):
    """A hot path as far as its lanes go (a :class:`~.hotpath.HotPath`)."""

    def lane_fds(self) -> list[int]: ...

    def lane_state(self, now: float) -> str: ...


class LaneWait:
    """The lane wait of one hot loop (nothing to wait on when no path has a lane).

    Parameters
    ----------
    paths : sequence of LanePath
        The loop's paths (those without lanes are left out).
    serving : int
        How many of the loop's paths have subscriptions to serve: if a path without lanes
        has some, the loop must wait on DDS.
    timed : bool
        Measure the loop's pauses (:attr:`meter`, which :attr:`woke_late_s` reads); else
        none and it stays 0.
    """

    def __init__(self, paths: Sequence[LanePath], serving: int, timed: bool = False) -> None:
        self.timed = timed
        self.paths = [p for p in paths if p.lane_fds()]
        self._all_served = len(self.paths) >= serving
        # the wake-up pipe, also for a loop without lanes that has no DDS reader to wait on
        # (:meth:`sleep`)
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._fds = [self._wake_r, *(fd for p in self.paths for fd in p.lane_fds())]
        self._mode, self._mode_until = DDS, -1.0
        #: the loop's pause meter (None: not ``timed``); the loop's other waits use it too
        self.meter = PauseMeter() if timed else None

    @property
    def woke_late_s(self) -> float:
        """How long after its timeout the last wait returned with no thread of the process
        running (s; 0: before it, or not ``timed``: :attr:`PauseMeter.woke_late_s`)."""
        return self.meter.woke_late_s if self.meter is not None else 0.0

    def __bool__(self) -> bool:
        return bool(self.paths)

    def mode(self) -> str:
        """How the loop waits: on the lanes alone (:data:`~.laneinput.LANES`), on them
        polling DDS (:data:`~.laneinput.MIXED`) or on DDS (:data:`~.laneinput.DDS`: no lane
        writer serves them yet, or a subscription without a lane is served too)."""
        now = time.monotonic()
        return self._mode if now < self._mode_until else self._judge(now)

    def _judge(self, now: float) -> str:
        states = {p.lane_state(now) for p in self.paths}
        if states == {DDS} or not self._all_served:
            mode = DDS
        else:
            mode = LANES if states == {LANES} else MIXED
        self._mode, self._mode_until = mode, (now + STATE_S if mode != DDS else -1.0)
        return mode

    def wait(self, timeout: float) -> bool:
        """Wait on the lanes (and the wake-up pipe) for at most ``timeout`` s, if a lane writer
        serves them; False (no wait) when none does: the loop waits on DDS then."""
        now = time.monotonic()  # mode() without its call: this runs at every wake-up
        mode = self._mode if now < self._mode_until else self._judge(now)
        if mode == DDS:
            return False
        if mode != LANES:
            timeout = min(timeout, DDS_POLL_S)
        meter = self.meter
        if meter is not None:
            meter.waiting(now, now + max(timeout, 0.0))
        ready, _, _ = select.select(self._fds, (), (), max(timeout, 0.0))
        if meter is not None:
            meter.woke()
        if self._wake_r in ready:
            with contextlib.suppress(OSError):
                os.read(self._wake_r, 4096)
        return True

    def sleep(self, timeout: float) -> None:
        """Wait on the wake-up pipe alone for at most ``timeout`` s (a loop with nothing else
        to wait on: the plant, whose inputs its tick drains; composed, every topic in
        process). One ``select``: ``threading.Event.wait`` with a timeout ran seven Python
        frames and made a lock at every wake-up."""
        ready, _, _ = select.select(self._fds[:1], (), (), max(timeout, 0.0))
        if ready:
            with contextlib.suppress(OSError):
                os.read(self._wake_r, 4096)

    def wake(self) -> None:
        """End a wait now (or the next one, if none is going on)."""
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):  # full: a wake-up is pending anyway
                os.write(self._wake_w, b"w")

    def close(self) -> None:
        """Close the wake-up pipe (idempotent; the FIFOs are the paths')."""
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._wake_r = self._wake_w = -1


__all__ = ["DDS_POLL_S", "LanePath", "LaneWait", "PauseMeter", "process_cpu_ns"]
