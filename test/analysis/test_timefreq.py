"""Spectrogram and BLRMS trends: scipy's spectrogram, the band integral of the PSD, a sine's
RMS; the report's figures with the mode switches."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from dcsms_ros.analysis import timefreq
from dcsms_ros.analysis.report import analyze
from dcsms_ros.errors import DcsmsError

FS = 2000.0


def test_spectrogram_equals_scipy() -> None:
    """The short-time PSD equals scipy.signal.spectrogram (Hann, half overlap, density)."""
    x = np.random.default_rng(1).standard_normal(int(60 * FS)).astype(np.float32)
    tf = timefreq.compute(x, FS)
    nper = timefreq.segment_length(FS, x.size)
    assert nper == 8192
    f, t, s = signal.spectrogram(x.astype(np.float64), FS, window="hann", nperseg=nper,
                                 noverlap=nper // 2, detrend="constant", scaling="density")
    keep = f <= timefreq.F_MAX_HZ
    np.testing.assert_allclose(tf.f_hz, f[keep])
    np.testing.assert_allclose(tf.t_s, t)
    np.testing.assert_allclose(tf.psd, s[keep], rtol=1e-5)


@pytest.mark.parametrize("f0, band, inside", [(5.0, (3.0, 10.0), True),
                                              (20.0, (3.0, 10.0), False)])
def test_blrms_of_a_sine(f0: float, band: tuple[float, float], inside: bool) -> None:
    """A 2 um/s sine: its RMS (1.414 um/s) in the band that holds it, ~nothing elsewhere."""
    t = np.arange(int(30 * FS)) / FS
    x = 2e-6 * np.sin(2 * np.pi * f0 * t)
    tf = timefreq.compute(x, FS, [band])
    expect = 2e-6 / np.sqrt(2) if inside else 0.0
    np.testing.assert_allclose(tf.blrms[0], expect, atol=0.02 * 2e-6)


def test_blrms_mean_square_is_the_welch_band_power() -> None:
    """Averaged over time, BLRMS^2 is the band integral of scipy's Welch PSD (same
    segments)."""
    rng = np.random.default_rng(2)
    x = signal.lfilter(*signal.butter(2, [2, 40], "bandpass", fs=FS), rng.standard_normal(
        int(120 * FS)))
    tf = timefreq.compute(x, FS, timefreq.DEFAULT_BANDS)
    nper = timefreq.segment_length(FS, x.size)
    f, p = signal.welch(x, FS, nperseg=nper)
    for (lo, hi), trend in zip(tf.bands, tf.blrms, strict=True):
        df = f[1] - f[0]
        w = np.clip(np.minimum(f + df / 2, hi) - np.maximum(f - df / 2, lo), 0, None)
        assert np.mean(trend ** 2) == pytest.approx(np.sum(p * w), rel=1e-6)


@pytest.mark.parametrize("text, message", [("3-1", "0 <= LO < HI"), ("a-b", "LO-HI"),
                                           ("", "no band")])
def test_parse_bands_refuses(text: str, message: str) -> None:
    with pytest.raises(DcsmsError, match=message):
        timefreq.parse_bands(text)


@pytest.mark.slow
def test_report_has_spectrogram_and_blrms(closed_loop_bag: Path, tmp_path: Path) -> None:
    """The report carries the spectrogram and the BLRMS trends of the whole bag, with the mode
    switch marked at 20 s and the excited span; every segment has its band RMS."""
    s = analyze([closed_loop_bag], out_dir=tmp_path, blrms_bands=[(1, 3), (3, 10)])
    ((i, axis, tf),) = s.timefreq
    assert (i, axis) == (0, "z")
    assert [lab for _, lab in tf.marks] == ["DFBC+FFC", "Passive"]
    assert tf.marks[1][0] == pytest.approx(20.0)
    assert tf.spans[0][0] == pytest.approx(0.0) and tf.spans[-1][1] == pytest.approx(30.0)
    assert tf.t_s[-1] > 35
    md = (tmp_path / "report.md").read_text()
    for name in ("spectrogram_z.png", "blrms_z.png"):
        assert (tmp_path / name).stat().st_size > 10_000 and f"({name})" in md
    for seg in s.segments:
        assert len(seg["axes"]["z"]["blrms_mps"]) == 2
    assert s.to_dict()["blrms_bands_hz"] == [[1, 3], [3, 10]]
