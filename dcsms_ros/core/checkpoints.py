"""The supervisor's view of a run, one :class:`~.supervisor.Checkpoint` per trip check: the
ground's band RMS through the trip's own band-pass and window, the actuator forces' peak, and
the stages' band RMS. The batch engine and the graph's mode switch build their checkpoints
here, so the supervisor sees the same numbers in both.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import actuator_limits
from dcsms_ros.core.sosfilter import BlockFilter, sosfilt
from dcsms_ros.core.supervisor import Checkpoint
from dcsms_ros.core.trip import CHECK_PERIOD_S, TripChecker, TripMonitor

Array = NDArray[np.float64]


class CheckpointFeed:
    """Builds each :class:`Checkpoint` from the samples of a run: the ground velocity through
    the trip's own band-pass and window, the actuator forces' peak over the same window.

    The forces of a checkpoint ending at sample k are those of samples k-W .. k-1 (W samples
    per window): the graph's plant applies sample k's forces only once the checkpoint has been
    judged (the verdict may disable controllers before they reach the plant), so the batch
    engine lags them by one sample too (:meth:`feed`).

    Parameters
    ----------
    cfg : SystemConfig
        The trip band and window (``control``), the actuator limits, the sample rate.
    """

    def __init__(self, cfg: SystemConfig, block_filter: BlockFilter = sosfilt) -> None:
        self.ground = TripMonitor(cfg.control, cfg.plant.rate_hz, cfg.plant.dof, block_filter)
        self.limit = actuator_limits(cfg)[1]
        self.dt = cfg.plant.dt
        self.window = max(1, int(round(cfg.control.trip_window_s / CHECK_PERIOD_S)))
        self.peaks: list[float] = []
        self.pending = 0.0
        self._carry: Array | None = None  # feed(): the newest force row, for the next window

    def feed_ground(self, ground: Array) -> None:
        """Ground twist rows ``(K, dof)`` (m/s) of the samples since the last call."""
        if ground.shape[0]:
            self.ground.update(ground)

    def feed_force(self, applied: Array) -> None:
        """Applied force rows ``(K, n_actuators)`` (N) that count in the next checkpoint."""
        if applied.shape[0]:
            self.pending = max(self.pending, float(np.max(np.abs(applied) / self.limit)))

    def feed(self, ground: Array, applied: Array) -> None:
        """Rows of the same samples (the batch engine): ground twist ``(K, dof)`` (m/s), forces
        ``(K, n_actuators)`` (N); the newest force row is held for the next checkpoint."""
        self.feed_ground(ground)
        if applied.shape[0]:
            if self._carry is not None:
                self.feed_force(self._carry)
            self.feed_force(applied[:-1])
            self._carry = applied[-1:].copy()

    def checkpoint(self, sample: int, checker: TripChecker) -> Checkpoint:
        """The checkpoint ending at ``sample`` (after the rows through it were fed), with the
        stage band RMS of ``checker``."""
        self.peaks = [*self.peaks[-(self.window - 1):], self.pending] if self.window > 1 \
            else [self.pending]
        self.pending = 0.0
        stage = np.array([m.rms for m in checker.monitors])
        return Checkpoint(sample, sample * self.dt, stage, self.ground.rms.copy(),
                          max(self.peaks))


__all__ = ["CheckpointFeed"]
