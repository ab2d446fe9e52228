"""Feeding the instability trip from the stage velocity topics, sample by sample in order.

The stage velocities arrive as one stream per stage (``velocity/stage<i>``); the trip checker
(:class:`dcsms_ros.core.trip.TripChecker`) wants rows of every stage for the same sample, in
order, from sample 0, so that its checkpoints (every :func:`~dcsms_ros.core.trip.check_samples`
samples) are the batch engine's. :class:`TripFeed` keeps each stream's samples by stamp, drops
repeats (lockstep retransmissions) and older stamps, and pushes the rows that every stage has,
up to a requested stamp (lockstep: the checkpoint the plant asks about) or as far as they go
(real time).
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.trip import Trip, TripChecker

Array = NDArray[np.float64]
NS = 1_000_000_000


class TripFeed:
    """Per-stage velocity streams in, aligned rows to a :class:`TripChecker` out.

    Parameters
    ----------
    checker : TripChecker
    rate_hz : float
        Sample rate (stamp -> sample index).

    Attributes
    ----------
    judged_ns : int
        Stamp of the newest row given to the checker (-1: none).
    trip_ns : int
        Stamp of the row whose checkpoint tripped (-1: none).
    gaps : int
        Samples missing between two fed rows (lockstep: must stay 0).
    """

    def __init__(self, checker: TripChecker, rate_hz: float) -> None:
        self.checker = checker
        self.rate = float(rate_hz)
        n = len(checker.monitors)
        self._queues: list[deque[tuple[int, Array]]] = [deque() for _ in range(n)]
        self._newest = [-1] * n
        self.judged_ns = -1
        self.trip_ns = -1
        self.gaps = 0
        self._align = False

    def index(self, stamp_ns: int) -> int:
        """Sample index of a stamp."""
        return int(round(stamp_ns * self.rate / NS))

    def add(self, stage: int, stamp_ns: int, v: Array) -> None:
        """Velocity ``v`` (dof,) m/s of stage ``stage`` (0-based) stamped ``stamp_ns``."""
        if stamp_ns <= self._newest[stage] or stamp_ns <= self.judged_ns:
            return  # a repeat (retransmission) or older
        self._newest[stage] = stamp_ns
        self._queues[stage].append((stamp_ns, v))

    def newest_ns(self) -> int:
        """Newest stamp any stage has arrived at (-1: none)."""
        return max(self._newest)

    def complete_ns(self) -> int:
        """Newest stamp every stage has arrived at (-1 while one has nothing)."""
        return min(self._newest)

    def judge(self, through_ns: int | None = None, lag_ns: int = 10_000_000) -> Trip | None:
        """Give the checker every aligned row of :meth:`take`.

        Returns the trip of a checkpoint among them (the rest of the rows are dropped then), or
        None.
        """
        stamps, rows = self.take(through_ns, lag_ns)
        if not rows:
            return None
        used, trip = self.checker.push(np.asarray(rows, dtype=np.float64))
        if trip is not None:
            self.trip_ns = stamps[used - 1]
        return trip

    def take(self, through_ns: int | None = None, lag_ns: int = 10_000_000
             ) -> tuple[list[int], list[list[Array]]]:
        """The aligned rows (stamps, one velocity per stage) up to ``through_ns`` (lockstep:
        each stage must have it) or, without it (real time), every row older than ``lag_ns``
        before the newest sample any stage has, a stage that lacks one counting zero there (a
        silent stream must not blind the trip); they count as judged."""
        strict = through_ns is not None
        upto = (min(self.complete_ns(), through_ns) if through_ns is not None
                else max(self._newest) - lag_ns)
        rows, stamps = [], []
        while True:
            heads = [q[0][0] for q in self._queues if q]
            if not heads or (strict and len(heads) < len(self._queues)):
                break
            s = max(heads) if strict else min(heads)
            if s > upto:
                break
            if strict and min(heads) != s:  # a stage lacks this sample: drop the older heads
                for q in self._queues:
                    if q[0][0] < s:
                        q.popleft()
                continue
            k = self.index(s)
            row = [q.popleft()[1] if q and q[0][0] == s else np.zeros(self.checker.dof)
                   for q in self._queues]
            if self._align and k % self.checker.every:
                self.judged_ns = s  # after a reset: wait for a checkpoint block's start
                continue
            if self.judged_ns >= 0 and not self._align:
                self.gaps += max(k - self.index(self.judged_ns) - 1, 0)
            self._align = False
            rows.append(row)
            stamps.append(s)
            self.judged_ns = s
        return stamps, rows

    def reset(self) -> None:
        """Forget the history; feeding resumes at the next checkpoint block's first sample, so
        the checkpoints keep their sample indices."""
        self.checker.reset()
        for q in self._queues:
            q.clear()
        self.trip_ns = -1
        self._align = True


__all__ = ["TripFeed"]
