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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.trip import Trip, TripChecker
from dcsms_ros.protocols.stampedrows import StampedRows, Stamps

Array = NDArray[np.float64]
NS = 1_000_000_000


def _same_stamps(parts: list[tuple[Stamps, Array]]) -> bool:
    """True if every stream's rows have the first one's stamps (one comparison per stream
    instead of the intersection and a scatter per stream: a lockstep checkpoint's case)."""
    s0 = parts[0][0]
    return all(s.size == s0.size and bool((s == s0).all()) for s, _ in parts[1:])


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
        self._streams = [StampedRows(checker.dof) for _ in checker.monitors]
        self.judged_ns = -1
        self.trip_ns = -1
        self.gaps = 0
        self._align = False

    def index(self, stamp_ns: int) -> int:
        """Sample index of a stamp."""
        return int(round(stamp_ns * self.rate / NS))

    def indices(self, stamps: Stamps) -> NDArray[np.int64]:
        """Sample indices of stamps (K,) ns, as :meth:`index` rounds them."""
        return np.rint(stamps * self.rate / NS).astype(np.int64)

    def add_block(self, stage: int, stamps: ArrayLike, v: ArrayLike) -> None:
        """Velocities ``v`` (K, dof) m/s of stage ``stage`` stamped ``stamps`` (K,) ns; a
        repeat (retransmission) or an older or already judged stamp is dropped."""
        self._streams[stage].extend(stamps, v, floor=self.judged_ns)

    def newest_ns(self) -> int:
        """Newest stamp any stage has arrived at (-1: none)."""
        return max(s.newest for s in self._streams)

    def complete_ns(self) -> int:
        """Newest stamp every stage has arrived at (-1 while one has nothing)."""
        return min(s.newest for s in self._streams)

    def judge(self, through_ns: int | None = None, lag_ns: int = 10_000_000) -> Trip | None:
        """Give the checker every aligned row of :meth:`take`.

        Returns the trip of a checkpoint among them (the rest of the rows are dropped then), or
        None.
        """
        stamps, rows = self.take(through_ns, lag_ns)
        if not stamps.size:
            return None
        used, trip = self.checker.push(rows)
        if trip is not None:
            self.trip_ns = int(stamps[used - 1])
        return trip

    def take(self, through_ns: int | None = None, lag_ns: int = 10_000_000
             ) -> tuple[Stamps, Array]:
        """The aligned rows up to ``through_ns`` (lockstep: only samples every stage has) or,
        without it (real time), every row older than ``lag_ns`` before the newest sample any
        stage has, a stage that lacks one counting zero there (a silent stream must not blind
        the trip); they count as judged.

        Returns
        -------
        stamps : ndarray of int64, shape (K,)
            ns, increasing.
        rows : ndarray, shape (K, num_stages, dof)
            m/s.
        """
        if through_ns is not None:
            upto = min(self.complete_ns(), through_ns)
            # a sample some stage lacks never completes (no stage takes an older stamp)
            parts = [st.take(upto) for st in self._streams]
            stamps = parts[0][0]
            if _same_stamps(parts):  # lockstep, nothing lost: the rows as they are
                return self._taken(stamps, np.stack([v for _, v in parts], axis=1))
            for s, _ in parts[1:]:
                stamps = np.intersect1d(stamps, s, assume_unique=True)
        else:
            upto = self.newest_ns() - lag_ns
            parts = [st.take(upto) for st in self._streams]
            stamps = np.unique(np.concatenate([s for s, _ in parts]))
        rows = np.zeros((stamps.size, len(parts), self.checker.dof))
        if not stamps.size:
            return stamps, rows
        for i, (s, v) in enumerate(parts):
            idx = np.minimum(np.searchsorted(stamps, s), stamps.size - 1)
            hit = stamps[idx] == s
            rows[idx[hit], i] = v[hit]
        return self._taken(stamps, rows)

    def _taken(self, stamps: Stamps, rows: Array) -> tuple[Stamps, Array]:
        """:meth:`take`'s end: the rows from a checkpoint block's start after a reset; the
        gaps counted; the newest stamp judged."""
        if not stamps.size:
            return stamps, rows
        k = self.indices(stamps)
        if self._align:
            # after a reset: wait for a checkpoint block's start
            start = np.flatnonzero(k % self.checker.every == 0)
            if not start.size:
                self.judged_ns = int(stamps[-1])
                return stamps[:0], rows[:0]
            stamps, rows, k = stamps[start[0]:], rows[start[0]:], k[start[0]:]
            self._align = False
        elif self.judged_ns >= 0:
            k = np.concatenate(([self.index(self.judged_ns)], k))
        self.gaps += int(np.maximum(np.diff(k) - 1, 0).sum())
        self.judged_ns = int(stamps[-1])
        return stamps, rows

    def reset(self) -> None:
        """Forget the history; feeding resumes at the next checkpoint block's first sample, so
        the checkpoints keep their sample indices."""
        self.checker.reset()
        for st in self._streams:
            st.clear()
        self.trip_ns = -1
        self._align = True


__all__ = ["TripFeed"]
