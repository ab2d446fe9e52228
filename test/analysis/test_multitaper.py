"""The whole-record band power (:mod:`dcsms_ros.analysis.multitaper`) against analytic values."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis.multitaper import band_power, psd_multitaper

FS = 200.0


def test_the_psd_integrates_to_the_variance() -> None:
    x = np.random.default_rng(3).standard_normal(4000) * 0.7
    f, p = psd_multitaper(x, FS)
    assert f[1] == pytest.approx(FS / x.size)
    assert_allclose(np.sum(p) * f[1], np.var(x), rtol=0.05)


def test_a_tone_in_the_band_under_a_huge_slow_drift() -> None:
    """A 2 Hz tone of amplitude 1e-3 (power 5e-7) under a 0.05 Hz drift 1e6 times stronger in
    power and a little white noise: the band power is the tone's, within 2 %; the filter, the
    padding and the tapers keep the drift out."""
    t = np.arange(int(24 * FS)) / FS
    rng = np.random.default_rng(5)
    x = (1e-3 * np.sin(2 * np.pi * 2.0 * t + 0.4) + 1.0 * np.sin(2 * np.pi * 0.05 * t + 1.0)
         + 1e-6 * rng.standard_normal(t.size))
    assert band_power(x, FS, 1.78, 2.24) == pytest.approx(0.5e-6, rel=0.02)


def test_a_sharp_resonance_keeps_its_power_in_the_band() -> None:
    """White noise through a 2 Hz resonance of 0.1 Hz half-power bandwidth, 24 s records (the
    Welch kernel of :func:`.estimators.choose_nperseg` spans +-0.5 Hz here, wider than the
    third-octave band): over 200 records the band power averages to the analytic integral of
    the filter's PSD within 3 standard errors, and the Welch band power of the same records
    falls short of it by more than 5 %."""
    f0, bw = 2.0, 0.1
    b, a = signal.iirpeak(f0, f0 / bw, fs=FS)
    lo, hi = f0 * 2 ** (-1 / 6), f0 * 2 ** (1 / 6)
    fine = np.linspace(lo, hi, 4001)
    _, h = signal.freqz(b, a, worN=fine, fs=FS)
    exact = float(np.trapezoid(2.0 / FS * np.abs(h) ** 2, fine))  # unit white noise, one-sided
    rng = np.random.default_rng(7)
    n = int(24 * FS)
    mt, welch = [], []
    for _ in range(200):
        y = signal.lfilter(b, a, rng.standard_normal(n + 4000))[4000:]
        mt.append(band_power(y, FS, lo, hi))
        f, p = est.psd(y, FS, est.choose_nperseg(FS, n))
        welch.append(est.band_rms_around(f, p, f0) ** 2)
    m, se = np.mean(mt), np.std(mt, ddof=1) / np.sqrt(len(mt))
    assert abs(m - exact) < 3 * se, (m / exact, se / exact)
    assert np.mean(welch) < 0.95 * exact, np.mean(welch) / exact
