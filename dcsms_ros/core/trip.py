"""Instability trip: band-limited RMS of each table velocity over a sliding window.

An unstable loop shows up as a growing oscillation inside the control band, so the velocity is
band-passed (``control.trip_band_hz``: drift and sensor noise outside it do not count) and its
RMS over ``control.trip_window_s`` compared with ``control.trip_rms_mps``.

Checkpoints make the trip land on a defined sample: :class:`TripChecker` judges the stage
velocities every :func:`check_samples` samples (:data:`CHECK_PERIOD_S` of plant time), after
sample k with ``(k + 1) % M == 0``; a trip found there disables every controller from sample
``k + 1`` on (their gains fade out over ``control.fade_time_s``). The batch engine feeds it its
own velocities; in lockstep the mode-switch node feeds it the decoupled velocity topics and the
plant waits for its verdict at each checkpoint, so both trip on the same sample.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import ControlConfig
from dcsms_ros.core.filterdesign import butter_sos, sos_steady_state
from dcsms_ros.core.sosfilter import BlockFilter, sosfilt

Array = NDArray[np.float64]


class TripMonitor:
    """Sliding-window band-limited RMS of ``channels`` velocity signals.

    Parameters
    ----------
    control : ControlConfig
        ``trip_band_hz`` [low, high] Hz, ``trip_window_s`` s, ``trip_rms_mps`` m/s.
    rate_hz : float
        Sample rate of the fed signals, Hz.
    channels : int
        Number of signals (e.g. the dof of one stage).
    block_filter : callable
        Runs the band-pass over a block (:data:`.sosfilter.BlockFilter`; the batch engine
        passes a compiled one with the same bits).
    """

    def __init__(self, control: ControlConfig, rate_hz: float, channels: int,
                 block_filter: BlockFilter = sosfilt) -> None:
        self._run = block_filter
        lo, hi = control.trip_band_hz
        nyq = rate_hz / 2.0
        # a corner at or above Nyquist, or at 0, degenerates the band-pass to one side
        if hi >= 0.95 * nyq and lo > 0.0:
            self.sos = butter_sos(2, lo, "highpass", rate_hz)
        elif lo <= 0.0 and hi < 0.95 * nyq:
            self.sos = butter_sos(2, hi, "lowpass", rate_hz)
        elif lo <= 0.0:
            self.sos = np.array([[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
        else:
            self.sos = butter_sos(2, (lo, hi), "bandpass", rate_hz)
        self.threshold = control.trip_rms_mps
        self.window = max(1, int(round(control.trip_window_s * rate_hz)))
        self.channels = channels
        self.reset()

    def reset(self) -> None:
        """Forget the history (filter states and window)."""
        self._zi = np.zeros((self.sos.shape[0], 2, self.channels))
        self._ring = np.zeros((self.window, self.channels))
        self._pos = 0
        self._started = False
        self.count = 0
        self.rms = np.zeros(self.channels)

    def filter(self, block: Array) -> Array:
        """Band-pass samples ``(K, channels)`` (m/s), carrying the filter state; the same
        numbers however the samples are split into calls."""
        x = np.asarray(block, dtype=np.float64).reshape(-1, self.channels)
        if x.shape[0] == 0:
            return x
        # a NaN or an absurd value (> 10 m/s) is a corrupt message, not instability (a
        # comparison with NaN is False and raises no floating-point flag)
        ok = np.abs(x) <= 10.0
        if not ok.all():
            x = np.where(ok, x, 0.0)
        if not self._started:
            # start the band-pass in the steady state of the first sample: a velocity offset
            # (sensor drift) must not ring through it as a false trip at start or after a reset
            self._zi = sos_steady_state(self.sos)[:, :, None] * x[0][None, None, :]
            self._started = True
        y, self._zi = self._run(self.sos, x, self._zi)
        return y

    def update(self, block: Array) -> Array:
        """Feed samples ``(K, channels)`` (m/s); return the RMS over the last window (m/s)."""
        return self.window_rms(self.filter(block))

    def window_rms(self, y: Array) -> Array:
        """Add band-passed samples ``(K, channels)`` (from :meth:`filter`) to the window;
        return the RMS over the last window (m/s)."""
        if y.shape[0] == 0:
            return self.rms
        k = y.shape[0]
        y = y[-self.window:]
        n = y.shape[0]
        # the ring as one or two slices (a checkpoint's block: no index array)
        pos, w = self._pos, self.window
        head = min(n, w - pos)
        self._ring[pos:pos + head] = y[:head] * y[:head]
        if head < n:
            self._ring[:n - head] = y[head:] * y[head:]
        self._pos = (pos + n) % w
        self.count += k
        filled = min(self.count, self.window)
        self.rms = np.sqrt(self._ring.sum(axis=0) / filled)
        return self.rms

    def tripped(self) -> bool:
        """True if some channel's RMS exceeds the threshold."""
        return bool((self.rms > self.threshold).any())


#: Plant time between two trip checkpoints, s.
CHECK_PERIOD_S = 0.05


def check_samples(rate_hz: float) -> int:
    """Samples between two checkpoints at ``rate_hz`` (Hz): :data:`CHECK_PERIOD_S`, >= 1."""
    return max(1, int(round(CHECK_PERIOD_S * rate_hz)))


@dataclass(frozen=True)
class Trip:
    """A trip: ``sample`` is the checkpoint's last sample k (the controllers are off from
    k + 1), ``stage`` 1-based, ``axis`` index into the stage's dof vector, ``rms`` (m/s)."""

    sample: int
    stage: int
    axis: int
    rms: float
    reason: str


class TripChecker:
    """Every stage's :class:`TripMonitor`, judged at checkpoints.

    Parameters
    ----------
    control : ControlConfig
    rate_hz : float
        Sample rate, Hz.
    num_stages, dof : int
        Shape of the stage velocities fed.
    block_filter : callable
        As for :class:`TripMonitor`.
    """

    def __init__(self, control: ControlConfig, rate_hz: float, num_stages: int,
                 dof: int, block_filter: BlockFilter = sosfilt) -> None:
        self.control = control
        self.every = check_samples(rate_hz)
        self.monitors = [TripMonitor(control, rate_hz, dof, block_filter)
                         for _ in range(num_stages)]
        self.dof = dof
        self.reset()

    def reset(self) -> None:
        """Forget the history; the next sample fed is a checkpoint block's first."""
        for m in self.monitors:
            m.reset()
        self._pending = np.zeros((0, len(self.monitors), self.dof))
        self.k = 0  # samples fed so far

    def clone(self) -> TripChecker:
        """An independent copy (to judge a block before committing to it)."""
        return copy.deepcopy(self)

    def push(self, velocity: Array) -> tuple[int, Trip | None]:
        """Feed stage velocities ``(K, N, dof)`` (m/s, samples in order) until a checkpoint
        trips.

        Every complete checkpoint block among them is band-passed in one call per stage (the
        same numbers as block by block), then judged in order.

        Returns
        -------
        consumed : int
            Rows taken: all of them, or through the tripping checkpoint's sample.
        trip : Trip or None
        """
        v = np.asarray(velocity, dtype=np.float64)
        p = self._pending.shape[0]
        blocks = (p + v.shape[0]) // self.every
        if blocks == 0:
            self._pending = np.concatenate([self._pending, v]) if p else v.copy()
            self.k += v.shape[0]
            return v.shape[0], None
        take = blocks * self.every - p
        x = np.concatenate([self._pending, v[:take]]) if p else v[:take]
        ys = [mon.filter(x[:, i]) for i, mon in enumerate(self.monitors)]
        for j in range(blocks):
            rows = slice(j * self.every, (j + 1) * self.every)
            trip = self._judge([y[rows] for y in ys], self.k - p + (j + 1) * self.every - 1)
            if trip is not None:
                used = (j + 1) * self.every - p
                self.k += used
                self._pending = np.zeros((0, len(self.monitors), self.dof))
                return used, trip
        self._pending = v[take:].copy()
        self.k += v.shape[0]
        return v.shape[0], None

    def _judge(self, filtered: list[Array], sample: int) -> Trip | None:
        worst: Trip | None = None
        for i, (mon, y) in enumerate(zip(self.monitors, filtered, strict=True)):
            rms = mon.window_rms(y)
            if mon.tripped() and worst is None:
                j = int(np.argmax(rms / mon.threshold))
                lo, hi = self.control.trip_band_hz
                worst = Trip(sample, i + 1, j, float(rms[j]),
                             f"stage{i + 1} velocity RMS {rms[j]:.3g} m/s (axis {j}) above "
                             f"{mon.threshold:g} m/s in {lo:g}-{hi:g} Hz")
        return worst


__all__ = ["CHECK_PERIOD_S", "Trip", "TripChecker", "TripMonitor", "check_samples"]
