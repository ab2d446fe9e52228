"""Instability trip: band-limited RMS of a table velocity over a sliding window (no rclpy).

An unstable loop shows up as a growing oscillation inside the control band, so the velocity is
band-passed (``control.trip_band_hz``: drift and sensor noise outside it do not count) and its
RMS over ``control.trip_window_s`` compared with ``control.trip_rms_mps``. Samples are fed in
blocks (the node buffers the stream and checks a few times per second); the filter state carries
across blocks, so the result does not depend on the block size.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.signal import butter, sosfilt, sosfilt_zi

from dcsms_ros.core.config import ControlConfig

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
    """

    def __init__(self, control: ControlConfig, rate_hz: float, channels: int) -> None:
        lo, hi = control.trip_band_hz
        nyq = rate_hz / 2.0
        # a corner at or above Nyquist, or at 0, degenerates the band-pass to one side
        if hi >= 0.95 * nyq and lo > 0.0:
            self.sos = butter(2, lo, btype="highpass", fs=rate_hz, output="sos")
        elif lo <= 0.0 and hi < 0.95 * nyq:
            self.sos = butter(2, hi, btype="lowpass", fs=rate_hz, output="sos")
        elif lo <= 0.0:
            self.sos = np.array([[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
        else:
            self.sos = butter(2, [lo, hi], btype="bandpass", fs=rate_hz, output="sos")
        self.threshold = control.trip_rms_mps
        self.window = max(1, int(round(control.trip_window_s * rate_hz)))
        self.channels = channels
        self.reset()

    def reset(self) -> None:
        """Forget the history (filter states and window)."""
        self._zi = np.zeros((self.sos.shape[0], 2, self.channels))
        self._ring = np.zeros((self.window, self.channels))
        self._pos = 0
        self.count = 0
        self.rms = np.zeros(self.channels)

    def update(self, block: Array) -> Array:
        """Feed samples ``(K, channels)`` (m/s); return the RMS over the last window (m/s)."""
        x = np.asarray(block, dtype=np.float64).reshape(-1, self.channels)
        if x.shape[0] == 0:
            return self.rms
        # a NaN or an absurd value (> 10 m/s) is a corrupt message, not instability
        with np.errstate(invalid="ignore"):
            x = np.where(np.abs(x) <= 10.0, x, 0.0)
        if self.count == 0:
            # start the band-pass in the steady state of the first sample: a velocity offset
            # (sensor drift) must not ring through it as a false trip at start or after a reset
            self._zi = sosfilt_zi(self.sos)[:, :, None] * x[0][None, None, :]
        y, self._zi = sosfilt(self.sos, x, axis=0, zi=self._zi)
        y = y[-self.window:]
        n = y.shape[0]
        idx = (self._pos + np.arange(n)) % self.window
        self._ring[idx] = y * y
        self._pos = (self._pos + n) % self.window
        self.count += x.shape[0]
        filled = min(self.count, self.window)
        self.rms = np.sqrt(self._ring.sum(axis=0) / filled)
        return self.rms

    def tripped(self) -> bool:
        """True if some channel's RMS exceeds the threshold."""
        return bool((self.rms > self.threshold).any())
