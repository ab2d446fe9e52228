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
from dcsms_ros.ros.pausemeter import PauseMeter

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
            meter.waiting(timeout)
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


__all__ = ["DDS_POLL_S", "LanePath", "LaneWait"]
