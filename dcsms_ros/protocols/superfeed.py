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

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.checkpoints import CheckpointFeed
from dcsms_ros.core.supervisor import Supervisor, Transition
from dcsms_ros.protocols.stampedrows import StampedRows
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
        self._ground = StampedRows(self.dof)
        self._force = StampedRows(checkpoints.limit.size)
        n = len(feed.checker.monitors)
        # the open checkpoint block: its stage rows (K, n, dof) and ground rows (K, dof)
        self._pending = np.zeros((0, n, self.dof))
        self._pending_ground = np.zeros((0, self.dof))

    def add_grounds(self, stamps: ArrayLike, v: ArrayLike) -> None:
        """Ground twists of several samples: stamps (K,) ns, ``v`` (K, dof) m/s."""
        self._ground.extend(stamps, v)

    def add_forces(self, stamps: ArrayLike, f: ArrayLike) -> None:
        """Applied forces of several samples: stamps (K,) ns, ``f`` (K, n_actuators) N."""
        self._force.extend(stamps, f)

    def complete(self, through_ns: int) -> bool:
        """Lockstep: every stream holds what the checkpoint ending at ``through_ns`` needs."""
        k = self.feed.index(through_ns)
        return (self.feed.complete_ns() >= through_ns and self._ground.newest >= through_ns
                and (k == 0 or self.feed.index(self._force.newest) >= k - 1))

    def newest_sample(self) -> int:
        """Index of the newest sample any stage stream has (-1: none)."""
        newest = self.feed.newest_ns()
        return self.feed.index(newest) if newest >= 0 else -1

    def step(self, through_ns: int | None = None) -> list[Transition]:
        """Judge every checkpoint whose rows are in (:meth:`TripFeed.take`); the
        supervisor's transitions, in order."""
        stamps, rows = self.feed.take(through_ns)
        if not stamps.size:
            return []
        # a stream that lacks a sample counts zero there
        ground = self._ground.take_at(stamps)
        rows = np.concatenate([self._pending, rows])
        ground = np.concatenate([self._pending_ground, ground])
        off = self._pending.shape[0]
        ends = np.flatnonzero((self.feed.indices(stamps) + 1) % self.feed.checker.every == 0)
        out: list[Transition] = []
        begin = 0
        for j in ends.tolist():
            s, end = int(stamps[j]), off + j + 1
            # one filter call per checkpoint block (the same numbers as row by row)
            self.feed.checker.push(rows[begin:end])
            self.cp.feed_ground(ground[begin:end])
            begin = end
            # forces of the samples before the checkpoint's last count in it
            _, forces = self._force.take(s, inclusive=False)
            self.cp.feed_force(forces)
            tr = self.sup.step(self.cp.checkpoint(self.feed.index(s), self.feed.checker))
            if tr is not None:
                out.append(tr)
        self._pending, self._pending_ground = rows[begin:].copy(), ground[begin:].copy()
        return out

    def reset(self) -> None:
        """After ``reset_trip``: the trip feed realigns to the next checkpoint block."""
        self.feed.reset()
        self._pending = self._pending[:0]
        self._pending_ground = self._pending_ground[:0]


__all__ = ["SupervisedFeed"]
