"""Feeding the supervisor from the graph's streams, checkpoint by checkpoint, as the batch
engine steps it (:meth:`dcsms_ros.core.engine.Simulation._supervise`).

Three kinds of stream arrive separately: the stage velocities (aligned by
:class:`~.tripfeed.TripFeed`), the ground velocity and the applied actuator forces. For the
checkpoint ending at sample k the supervisor needs the ground through k and the forces through
k - 1 (the plant applies sample k's forces after the verdict;
:class:`~dcsms_ros.core.supervisor.CheckpointFeed`). :meth:`SupervisedFeed.step` walks the
aligned rows, pushes each checkpoint block to the trip checker, feeds the ground and forces of
the same samples, and steps the supervisor at every checkpoint; a stream that lacks a sample
counts zero there (real time), as the trip feed does.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.checkpoints import CheckpointFeed
from dcsms_ros.core.supervisor import Supervisor, Transition
from dcsms_ros.protocols.tripfeed import TripFeed

Array = NDArray[np.float64]


class SupervisedFeed:
    """Stage, ground and force streams in; supervisor transitions out.

    Parameters
    ----------
    feed : TripFeed
        The stage velocities and the trip checker.
    checkpoints : CheckpointFeed
        Ground band RMS and force peaks of each checkpoint.
    supervisor : Supervisor
    """

    def __init__(self, feed: TripFeed, checkpoints: CheckpointFeed,
                 supervisor: Supervisor) -> None:
        self.feed, self.cp, self.sup = feed, checkpoints, supervisor
        self.dof = feed.checker.dof
        self._ground: deque[tuple[int, Array]] = deque()
        self._force: deque[tuple[int, Array]] = deque()
        self._newest_ground = -1
        self._newest_force = -1
        self._pending: list[list[Array]] = []  # stage rows of the open checkpoint block
        self._pending_ground: list[Array] = []  # its ground rows

    def add_ground(self, stamp_ns: int, v: Array) -> None:
        """Ground twist ``v`` (dof,) m/s of the sample stamped ``stamp_ns``."""
        if stamp_ns > self._newest_ground:
            self._newest_ground = stamp_ns
            self._ground.append((stamp_ns, v))

    def add_force(self, stamp_ns: int, f: Array) -> None:
        """Applied actuator forces ``f`` (n_actuators,) N of the sample stamped ``stamp_ns``."""
        if stamp_ns > self._newest_force:
            self._newest_force = stamp_ns
            self._force.append((stamp_ns, f))

    def add_grounds(self, stamps: Array, v: Array) -> None:
        """Ground twists of several samples: stamps (K,) ns, ``v`` (K, dof) m/s."""
        for s, row in zip(stamps.tolist(), v, strict=True):
            self.add_ground(s, row)

    def add_forces(self, stamps: Array, f: Array) -> None:
        """Applied forces of several samples: stamps (K,) ns, ``f`` (K, n_actuators) N."""
        for s, row in zip(stamps.tolist(), f, strict=True):
            self.add_force(s, row)

    def complete(self, through_ns: int) -> bool:
        """Lockstep: every stream holds what the checkpoint ending at ``through_ns`` needs."""
        k = self.feed.index(through_ns)
        return (self.feed.complete_ns() >= through_ns and self._newest_ground >= through_ns
                and (k == 0 or self.feed.index(self._newest_force) >= k - 1))

    def newest_sample(self) -> int:
        """Index of the newest sample any stage stream has (-1: none)."""
        newest = self.feed.newest_ns()
        return self.feed.index(newest) if newest >= 0 else -1

    def step(self, through_ns: int | None = None) -> list[Transition]:
        """Judge every checkpoint whose rows are in (:meth:`TripFeed.take`); the
        supervisor's transitions, in order."""
        stamps, rows = self.feed.take(through_ns)
        out: list[Transition] = []
        every = self.feed.checker.every
        for s, row in zip(stamps, rows, strict=True):
            self._pending.append(row)
            self._pending_ground.append(self._take_ground(s))
            k = self.feed.index(s)
            if (k + 1) % every:
                continue
            # one filter call per checkpoint block (the same numbers as row by row)
            self.feed.checker.push(np.asarray(self._pending, dtype=np.float64))
            self.cp.feed_ground(np.asarray(self._pending_ground, dtype=np.float64))
            self._pending, self._pending_ground = [], []
            self._feed_forces_before(s)
            tr = self.sup.step(self.cp.checkpoint(k, self.feed.checker))
            if tr is not None:
                out.append(tr)
        return out

    def _take_ground(self, s: int) -> Array:
        while self._ground and self._ground[0][0] < s:
            self._ground.popleft()
        if self._ground and self._ground[0][0] == s:
            return self._ground.popleft()[1]
        return np.zeros(self.dof)

    def _feed_forces_before(self, s: int) -> None:
        """Forces of the samples before ``s`` count in the checkpoint ending at ``s``."""
        rows = []
        while self._force and self._force[0][0] < s:
            rows.append(self._force.popleft()[1])
        if rows:
            self.cp.feed_force(np.asarray(rows, dtype=np.float64))

    def reset(self) -> None:
        """After ``reset_trip``: the trip feed realigns to the next checkpoint block."""
        self.feed.reset()
        self._pending, self._pending_ground = [], []


__all__ = ["SupervisedFeed"]
