"""Time-frequency view of a whole bag: spectrogram and band-limited RMS (BLRMS) trends.

Both come from one short-time Welch computation of the top-stage velocity: Hann segments of
:data:`SEGMENT_S` (rounded to a power of two of samples), half overlapping, each turned into a
one-sided PSD exactly as :func:`.estimators.welch_sums` does for one segment. The spectrogram
keeps the PSD up to :data:`F_MAX_HZ`; the BLRMS of a band [lo, hi] at a time is
``sqrt(sum(PSD * df))`` over that band's bins (bins straddling an edge are split, as
:func:`.estimators.band_rms` does), so the BLRMS trend and the spectrogram tell the same story.
The segments are transformed a block at a time: an hour-long bag needs a few MB of work arrays
and keeps ~2 MB per axis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import signal

from dcsms_ros.analysis import estimators as est
from dcsms_ros.errors import DcsmsError

#: Target segment length (s): 0.25 Hz resolution at any rate, a column every ~2 s.
SEGMENT_S = 4.0
#: The spectrogram keeps frequencies up to this (Hz).
F_MAX_HZ = 200.0
#: Default BLRMS bands (Hz).
DEFAULT_BANDS = ((1.0, 3.0), (3.0, 10.0), (10.0, 30.0))
BLOCK = 64


@dataclass
class TimeFrequency:
    """Spectrogram and BLRMS of one signal.

    Attributes
    ----------
    t_s : ndarray, shape (T,)
        Centre of each segment, s from the first sample.
    f_hz : ndarray, shape (F,)
        Frequencies 0 .. :data:`F_MAX_HZ` (Hz).
    psd : ndarray of float32, shape (F, T)
        One-sided PSD per segment (unit^2/Hz).
    bands : list of (float, float)
        BLRMS bands (Hz).
    blrms : ndarray, shape (B, T)
        RMS in each band per segment (unit).
    """

    t_s: np.ndarray
    f_hz: np.ndarray
    psd: np.ndarray
    bands: list[tuple[float, float]]
    blrms: np.ndarray
    marks: list[tuple[float, str]] = field(default_factory=list)
    spans: list[tuple[float, float]] = field(default_factory=list)


def parse_bands(text: str) -> list[tuple[float, float]]:
    """``1-3,3-10,10-30`` -> [(1, 3), (3, 10), (10, 30)] (Hz).

    Raises
    ------
    DcsmsError
        A band that is not ``LO-HI`` with 0 <= LO < HI.
    """
    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        parts = item.split("-")
        try:
            lo, hi = (float(p) for p in parts) if len(parts) == 2 else (np.nan, np.nan)
        except ValueError:
            lo = hi = np.nan
        if not 0 <= lo < hi:
            raise DcsmsError(f"--blrms {item!r}: expected LO-HI in Hz with 0 <= LO < HI")
        out.append((lo, hi))
    if not out:
        raise DcsmsError("--blrms: no band given")
    return out


def segment_length(fs: float, n: int) -> int:
    """Samples per segment: the power of two nearest :data:`SEGMENT_S` s, at most ``n``."""
    nper = 1 << int(round(np.log2(max(fs * SEGMENT_S, 16.0))))
    while nper > n and nper > 16:
        nper //= 2
    return nper


def compute(x: np.ndarray, fs: float, bands: Sequence[tuple[float, float]] = DEFAULT_BANDS,
            nperseg: int | None = None) -> TimeFrequency:
    """Spectrogram and BLRMS of ``x`` (module docstring).

    Parameters
    ----------
    x : ndarray, shape (N,)
        Uniformly sampled record (float32 or float64; unit u).
    fs : float
        Sample rate, Hz.
    bands : sequence of (lo, hi)
        BLRMS bands, Hz.
    nperseg : int, optional
        Segment length (default :func:`segment_length`).
    """
    n = int(np.shape(x)[0])
    nper = nperseg or segment_length(fs, n)
    if n < nper:
        raise DcsmsError(f"time-frequency view: {n} samples, fewer than one segment ({nper})")
    step = nper // 2
    win = signal.get_window("hann", nper)
    f = np.fft.rfftfreq(nper, 1.0 / fs)
    keep = f <= F_MAX_HZ
    scale = est.density_scale(win, fs)
    view = sliding_window_view(np.asarray(x), nper)[::step]
    cols = []
    for b in range(0, view.shape[0], BLOCK):
        seg = view[b:b + BLOCK].astype(np.float64)
        seg -= seg.mean(axis=1, keepdims=True)
        z = np.fft.rfft(seg * win, axis=1)
        cols.append(((z.real ** 2 + z.imag ** 2) * scale)[:, keep])
    psd = np.vstack(cols).T  # (F, T)
    t = (np.arange(psd.shape[1]) * step + nper / 2) / fs
    band_arr = np.array([[np.sqrt(lo * hi), lo, hi] for lo, hi in bands])
    blrms = est.band_rms(f[keep], psd, band_arr)
    return TimeFrequency(t, f[keep], psd.astype(np.float32), list(bands), blrms)


__all__ = ["DEFAULT_BANDS", "TimeFrequency", "compute", "parse_bands", "segment_length"]
