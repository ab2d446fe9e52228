"""What the floor explains: the stage band RMS the loop model predicts per unit ground band RMS,
the ``band_gain`` of :class:`~dcsms_ros.core.supervisor.Supervisor`.

The ground is taken white within the trip band and equally loud on every axis (its axes
uncorrelated), so the gain of stage axis j is
``sqrt(sum_g int |H_jg(f)|^2 |B(f)|^2 df / int |B(f)|^2 df)`` with ``H`` the closed loop from
ground twist to true stage twist in the running mode and ``B`` the trip's band-pass; the
supervisor multiplies it by the loudest ground axis. A coloured floor moves the figure by the
ratio of its spectrum's weights, which ``excess_ratio`` leaves room for.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.filterdesign import sos_response
from dcsms_ros.core.loop_model import freq_response, loop_model
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.trip import TripMonitor

Array = NDArray[np.float64]

#: Frequencies of the integral (log-spaced from FMIN_HZ to Nyquist).
POINTS = 4000
FMIN_HZ = 0.01


def floor_gain(cfg: SystemConfig, mode: Mode) -> Array:
    """Stage band RMS per unit ground band RMS in ``mode``, shape (N, dof), 1."""
    fs = cfg.plant.rate_hz
    f = np.geomspace(FMIN_HZ, 0.499 * fs, POINTS)
    sos = TripMonitor(cfg.control, fs, 1).sos
    b = sos_response(sos, f, fs)
    w = np.abs(b) ** 2
    h = freq_response(loop_model(cfg, mode).select("ground", "velocity"), f)  # (F, N*dof, dof)
    power = np.trapezoid((np.abs(h) ** 2).sum(axis=2) * w[:, None], f, axis=0)
    gain = np.sqrt(power / np.trapezoid(w, f))[cfg.plant.dof:]  # the ground rows first
    return np.asarray(gain.reshape(cfg.plant.num_stages, cfg.plant.dof))


__all__ = ["floor_gain"]
