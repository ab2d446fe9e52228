"""Welch H1, ASD, peak picking and one-third-octave band RMS on signals with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from dcsms_ros.analysis import estimators as est

FS = 500.0


def test_h1_recovers_second_order_system() -> None:
    """H1 of a 2nd-order resonance driven by white noise is within 0.5 dB where coherence > 0.9."""
    rng = np.random.default_rng(0)
    x = rng.standard_normal(int(200 * FS))
    wn, zeta = 2 * np.pi * 5.0, 0.1  # 2nd-order resonance at 5 Hz
    b, a = signal.bilinear([wn**2], [1.0, 2 * zeta * wn, wn**2], fs=FS)
    sos = signal.tf2sos(b, a)
    y = signal.sosfilt(sos, x) + 1e-5 * rng.standard_normal(x.size)  # sensor noise
    tf = est.transfer_h1(x, y, FS)
    _, h_true = signal.sosfreqz(sos, worN=tf.f, fs=FS)
    good = (tf.coherence > 0.9) & (tf.f > 0.5) & (tf.f < 100.0)  # the analysis band
    assert good.sum() > 100
    err = 20 * np.log10(np.abs(tf.h[good]) / np.abs(h_true[good]))
    assert np.max(np.abs(err)) < 0.5
    assert 0.1 <= FS / est.choose_nperseg(FS, x.size) <= 0.25
    peaks = est.find_resonances(tf.f, np.abs(tf.h))
    assert abs(peaks[0].f_hz - 5.0) < 0.3


def test_third_octave_rms_of_sine() -> None:
    """A sine at a band centre gives amplitude/sqrt(2) in that band and little elsewhere."""
    t = np.arange(int(120 * FS)) / FS
    amp = 3e-6
    x = amp * np.sin(2 * np.pi * 10.0 * t)
    f, p = est.psd(x, FS)
    bands = est.third_octave_bands(1.0, 80.0)
    rms = est.band_rms(f, p, bands)
    j = int(np.argmin(np.abs(bands[:, 0] - 10.0)))
    assert abs(rms[j] / (amp / np.sqrt(2)) - 1) < 0.01
    assert np.sqrt(np.sum(np.delete(rms, j) ** 2)) < 0.02 * rms[j]


def test_band_rms_partitions_white_noise_power() -> None:
    """Band RMS values of white noise add up to its RMS over the covered range."""
    rng = np.random.default_rng(1)
    x = rng.standard_normal(int(100 * FS))
    f, p = est.psd(x, FS)
    bands = est.third_octave_bands(1.0, 80.0)
    total = np.sqrt(np.sum(est.band_rms(f, p, bands) ** 2))
    expected = np.sqrt(np.mean(p) * (bands[-1, 2] - bands[0, 1]))
    assert abs(total / expected - 1) < 0.03
    assert np.allclose(bands[:, 2] / bands[:, 1], 10 ** 0.1)  # base-10 third octaves
    assert len(bands) == len(est.NOMINAL_CENTRES)


def test_asd_level_of_white_noise() -> None:
    """The ASD of unit-variance white noise sampled at fs is sqrt(2/fs) (one-sided)."""
    rng = np.random.default_rng(2)
    f, a = est.asd(rng.standard_normal(int(100 * FS)), FS)
    assert abs(np.median(a[(f > 5) & (f < 200)]) / np.sqrt(2 / FS) - 1) < 0.05


@pytest.mark.parametrize(("n", "nperseg", "block"), [
    (100_000, 8192, 64), (20_000, 1024, 7), (5_000, 1000, 3), (4_096, 4_096, 64),
    (70_001, 4097, 5)])
def test_blockwise_welch_equals_scipy(n: int, nperseg: int, block: int) -> None:
    """The bounded-memory Welch sums equal scipy's welch/csd (float32 input, any block size)."""
    rng = np.random.default_rng(n)
    x = rng.standard_normal(n).astype(np.float32)
    y = (np.convolve(x, [1.0, 0.5, 0.2], "same")
         + 0.1 * rng.standard_normal(n)).astype(np.float32)
    kw = {"fs": FS, "window": "hann", "nperseg": nperseg, "noverlap": nperseg // 2,
          "detrend": "constant"}
    f_ref, sxx = signal.welch(x.astype(np.float64), **kw)
    _, syy = signal.welch(y.astype(np.float64), **kw)
    _, sxy = signal.csd(x.astype(np.float64), y.astype(np.float64), **kw)
    f, spectra, averages = est.welch_sums(x, y, FS, nperseg, block=block)
    np.testing.assert_allclose(f, f_ref)
    for got, want in zip(spectra, (sxx, syy, sxy), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.max(np.abs(want)))
    assert averages == (n - nperseg) // (nperseg - nperseg // 2) + 1
