"""Confidence intervals of band-RMS ratios (Table 4's values) from the records themselves.

A band power is the mean square of the band-passed signal ``y`` over the record (the Welch
band integral estimates the same quantity). For a Gaussian process the mean of ``y^2`` over
``T`` seconds has the variance ``(1/T) R(0)^2 int rho(tau)^2 (1 - |tau|/T) dtau``, with
``rho`` the normalised envelope autocorrelation of ``y``; so it behaves as a scaled chi-square
variable with

    nu = 2 T / int rho(tau)^2 (1 - |tau|/T) dtau

degrees of freedom (``2 pi B T`` for a resonance of half-power bandwidth ``B``). ``rho`` is
estimated from the record (analytic signal, up to the lag where it meets its own noise, at
most :data:`LAG_FRACTION` of the record), so a sharp
resonance, whose few degrees of freedom a per-bin Welch count overestimates (table1's Passive
peak is narrower than a 24 s record's bins), gets its due width. The ratio of two independent
band powers is then F-distributed, and the interval of ``sqrt(P_a / P_b)`` is

    [sqrt(R / F(1 - alpha/2; nu_a, nu_b)), sqrt(R / F(alpha/2; nu_a, nu_b))],  R = P_a / P_b.

Measured coverage of the 95 % interval against the batch engine and the loop model:
``test/analysis/test_uncertainty.py`` and docs/tem.md.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import signal, stats

from dcsms_ros.analysis.multitaper import KEEP_RATE_FACTOR

Array = NDArray[np.float64]

#: Confidence level of the intervals Table 4 reports.
LEVEL = 0.95
#: Longest lag of the autocorrelation integral, as a fraction of the record: beyond it the
#: estimate is mostly noise (which only widens the interval).
LAG_FRACTION = 0.25
#: Order of the Butterworth band-pass (applied forwards and backwards) that isolates the band.
BAND_ORDER = 4


def band_dof(x: Array, fs: float, lo_hz: float, hi_hz: float,
             lag_fraction: float = LAG_FRACTION) -> float:
    """Equivalent degrees of freedom of the power of ``x`` (sampled at ``fs`` Hz) between
    ``lo_hz`` and ``hi_hz`` (Hz) over the whole record; nan for a record too short or silent."""
    v = np.asarray(x, dtype=np.float64)
    if v.size < 16 or not 0.0 < lo_hz < hi_hz < fs / 2.0:
        return float("nan")
    sos = signal.butter(BAND_ORDER, [lo_hz, hi_hz], btype="bandpass", fs=fs, output="sos")
    # every q-th sample of the band-passed record (what folds into the band is 100+ dB down):
    # the envelope's autocorrelation of an hour at 2 kHz then takes ~10 MB, not ~1.5 GB
    q = max(1, int(fs / (KEEP_RATE_FACTOR * hi_hz)))
    v = v - v.mean()
    y = signal.sosfiltfilt(sos, v)[::q].copy()  # a copy: the full-rate record is freed
    return envelope_dof(y, fs / q, hi_hz - lo_hz, lag_fraction)


def envelope_dof(y: Array, fs: float, width_hz: float,
                 lag_fraction: float = LAG_FRACTION) -> float:
    """Equivalent degrees of freedom of the mean square of ``y``, a record already band-passed
    to a band ``width_hz`` (Hz) wide, sampled at ``fs`` Hz (the module notes); nan for a record
    too short or silent."""
    v = np.asarray(y, dtype=np.float64)
    n = v.size
    if n < 16 or not width_hz > 0.0:
        return float("nan")
    z = signal.hilbert(v)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spec = np.fft.fft(z, size)
    r = np.abs(np.fft.ifft(spec * np.conj(spec))[:n])
    if not r[0] > 0:
        return float("nan")
    rho = r / r[0]
    # the estimate's own noise, ~1/sqrt(T B) with B <= the band's width, would add to every
    # lag's rho^2: integrate up to where rho first falls to it (what a decay loses beyond that
    # is rho^2 there, ~5 %), at most lag_fraction of the record
    floor = 1.0 / np.sqrt(n / fs * width_hz)
    below = np.flatnonzero(rho[1:] < floor)
    lags = max(min(int(below[0]) + 1 if below.size else n, int(lag_fraction * n)), 1)
    rho2 = rho[:lags] ** 2 * (1.0 - np.arange(lags) / n)
    integral = 2.0 * rho2.sum() - rho2[0]
    end = rho[lags - 1]
    if 0.0 < end < 1.0 and lags > 1:
        # the exponential envelope of a resonance beyond the cut: rho(L)^2 L / (2 ln(1/rho(L)))
        integral += 2.0 * end * end * lags / (2.0 * np.log(1.0 / end))
    return float(2.0 * n / integral)


def ratio_interval(ratio: float, dof_num: float, dof_den: float,
                   level: float = LEVEL) -> tuple[float, float]:
    """Interval of a band-RMS ratio ``ratio = sqrt(P_num / P_den)`` whose band powers have
    ``dof_num`` and ``dof_den`` equivalent degrees of freedom (independent records); (nan, nan)
    when either is unknown."""
    if not (np.isfinite(ratio) and dof_num > 0 and dof_den > 0):
        return float("nan"), float("nan")
    alpha = 1.0 - level
    r2 = ratio * ratio
    lo = r2 / float(stats.f.ppf(1.0 - alpha / 2.0, dof_num, dof_den))
    hi = r2 / float(stats.f.ppf(alpha / 2.0, dof_num, dof_den))
    return float(np.sqrt(lo)), float(np.sqrt(hi))


__all__ = ["BAND_ORDER", "LAG_FRACTION", "LEVEL", "band_dof", "envelope_dof", "ratio_interval"]
