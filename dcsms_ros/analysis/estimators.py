"""Spectral estimators: Welch H1 transfer function, coherence, ASD, peaks, third-octave RMS.

All spectra are one-sided Welch estimates with a Hann window and 50 % overlap. ``nperseg`` is
a power of two giving a 0.1-0.25 Hz resolution (8192 or 16384 points at 2 kHz), reduced for
short records so that at least ~8 averages remain: with fewer, the coherence is biased towards
1 and the H1 variance is large.

The Welch sums are accumulated :data:`BLOCK_SEGMENTS` segments at a time from strided views of
the input (float32 or float64), so an hour-long record at 2 kHz costs a few MB of work arrays
instead of float64 copies and an FFT matrix of the whole record (scipy's ``welch``/``csd``
build both); the result equals scipy's to rounding (``test_welch_estimators.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import signal

#: Target resolution range (Hz) for :func:`choose_nperseg`.
RESOLUTION_HZ = (0.1, 0.25)
MIN_AVERAGES = 8
#: Welch segments transformed per block: bounds the work arrays (64 x 16384 x 16 B = 16 MB).
BLOCK_SEGMENTS = 64


@dataclass
class TransferEstimate:
    """H1 estimate of y/x.

    Attributes
    ----------
    f : ndarray, shape (F,)
        Frequencies (Hz).
    h : ndarray of complex, shape (F,)
        H1 = S_xy / S_xx (unit of y per unit of x).
    coherence : ndarray, shape (F,)
        Magnitude-squared coherence in [0, 1].
    averages : int
        Number of Welch segments averaged.
    """

    f: np.ndarray
    h: np.ndarray
    coherence: np.ndarray
    averages: int

    @property
    def magnitude_db(self) -> np.ndarray:
        """20 log10 |H| (dB), shape (F,)."""
        return 20.0 * np.log10(np.maximum(np.abs(self.h), 1e-300))


@dataclass
class Peak:
    """A resonance peak: frequency (Hz), value at the peak and its prominence (dB)."""

    f_hz: float
    value: float
    prominence_db: float


def choose_nperseg(fs: float, n: int) -> int:
    """Welch segment length for sample rate ``fs`` (Hz) and record length ``n`` (samples).

    The largest power of two with resolution ``fs/nperseg`` >= 0.1 Hz, reduced (by halving) until
    the record holds :data:`MIN_AVERAGES` half-overlapping segments; at least 64.
    """
    nper = 1 << int(np.floor(np.log2(fs / RESOLUTION_HZ[0])))
    while nper > 64 and (n - nper) // (nper // 2) + 1 < MIN_AVERAGES:
        nper //= 2
    return int(min(nper, max(n, 1)))


def h1_random_error(coherence: np.ndarray, averages: int) -> np.ndarray:
    """Normalised random error of |H1| (Bendat & Piersol): sqrt(1 - g2) / (|g| sqrt(2 n_d)).

    Uncorrelated output noise (here: table forces, sensor noise) leaves H1 unbiased but
    scatters it; this is the 1-sigma relative scatter, inf where the coherence is 0.
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    with np.errstate(divide="ignore"):
        return np.sqrt(1.0 - g2) / (np.sqrt(g2) * np.sqrt(2.0 * max(averages, 1)))


def welch_averages(n: int, nperseg: int) -> int:
    """Half-overlapping segments of ``nperseg`` samples in a record of ``n`` samples."""
    return max((n - nperseg) // (nperseg // 2) + 1, 0)


def density_scale(win: np.ndarray, fs: float) -> np.ndarray:
    """Factor turning ``|rfft(segment * win)|^2`` into a one-sided PSD (unit^2/Hz), shape
    (nperseg // 2 + 1,): density scaling, every bin but DC (and Nyquist for an even length)
    doubled."""
    n = win.size
    scale = np.full(n // 2 + 1, 2.0 / (fs * float(np.sum(win ** 2))))
    scale[0] /= 2.0
    if n % 2 == 0:
        scale[-1] /= 2.0
    return scale


def welch_sums(x: np.ndarray, y: np.ndarray | None, fs: float, nperseg: int,
               block: int = BLOCK_SEGMENTS) -> tuple[np.ndarray, list[np.ndarray], int]:
    """One-sided Welch (cross) spectral densities, as scipy's ``welch``/``csd`` with a Hann
    window, 50 % overlap, constant detrend and mean averaging, in bounded memory.

    Parameters
    ----------
    x, y : ndarray, shape (N,)
        Records on one uniform time base (float32 or float64; unit u_x, u_y); ``y`` may be None.
    fs : float
        Sample rate (Hz).
    nperseg : int
        Segment length (samples), <= N.
    block : int
        Segments transformed at a time.

    Returns
    -------
    f : ndarray, shape (nperseg // 2 + 1,)
        Frequencies (Hz).
    spectra : list of ndarray
        ``[S_xx]`` (u_x^2/Hz), or ``[S_xx, S_yy, S_xy]`` with ``S_xy = conj(X) Y`` (complex).
    averages : int
        Segments averaged.
    """
    step = nperseg - nperseg // 2
    win = signal.get_window("hann", nperseg)
    views = [sliding_window_view(np.asarray(r), nperseg)[::step]
             for r in ((x,) if y is None else (x, y))]
    nseg = views[0].shape[0]
    nf = nperseg // 2 + 1
    auto = [np.zeros(nf) for _ in views]
    cross = np.zeros(nf, dtype=complex)
    for b in range(0, nseg, block):
        ffts = []
        for v, acc in zip(views, auto, strict=True):
            seg = v[b:b + block].astype(np.float64)
            seg -= seg.mean(axis=1, keepdims=True)
            z = np.fft.rfft(seg * win, axis=1)
            np.add(acc, np.sum(z.real ** 2 + z.imag ** 2, axis=0), out=acc)
            ffts.append(z)
        if len(ffts) == 2:
            cross += np.sum(np.conj(ffts[0]) * ffts[1], axis=0)
    scale = density_scale(win, fs) / max(nseg, 1)
    spectra = [a * scale for a in auto]
    if y is not None:
        spectra.append(cross * scale)
    return np.fft.rfftfreq(nperseg, 1.0 / fs), spectra, nseg


def transfer_h1(x: np.ndarray, y: np.ndarray, fs: float,
                nperseg: int | None = None) -> TransferEstimate:
    """Welch H1 estimate of the transfer function from ``x`` to ``y`` and their coherence.

    Parameters
    ----------
    x, y : ndarray, shape (N,)
        Input and output records on the same uniform time base.
    fs : float
        Sample rate (Hz).
    nperseg : int, optional
        Segment length; default :func:`choose_nperseg`.
    """
    nper = nperseg or choose_nperseg(fs, np.shape(x)[0])
    f, (sxx, syy, sxy), _ = welch_sums(x, y, fs, nper)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(sxx > 0, sxy / sxx, 0.0)
        coh = np.where(sxx * syy > 0, np.abs(sxy) ** 2 / (sxx * syy), 0.0)
    return TransferEstimate(f, h, np.clip(coh.real, 0.0, 1.0),
                            welch_averages(np.shape(x)[0], nper))


def psd(x: np.ndarray, fs: float, nperseg: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD (unit^2/Hz) of ``x`` (N,): returns ``(f (F,), psd (F,))``."""
    nper = nperseg or choose_nperseg(fs, np.shape(x)[0])
    f, (p,), _ = welch_sums(x, None, fs, nper)
    return f, p


def asd(x: np.ndarray, fs: float, nperseg: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One-sided ASD (unit/sqrt(Hz), e.g. m/s/sqrt(Hz) for a velocity) of ``x`` (N,)."""
    f, p = psd(x, fs, nperseg)
    return f, np.sqrt(p)


def find_resonances(f: np.ndarray, magnitude: np.ndarray, prominence_db: float = 3.0,
                    f_range: tuple[float, float] = (0.5, 100.0),
                    max_peaks: int = 5) -> list[Peak]:
    """Resonance peaks of a magnitude spectrum (|H| or ASD), strongest first.

    Peaks are found on the dB curve (20 log10) with :func:`scipy.signal.find_peaks` and a
    prominence threshold, so a broad resonance and a tall narrow one are judged alike and
    noise ripples of a fraction of a dB are ignored.

    Parameters
    ----------
    f : ndarray, shape (F,)
        Frequencies (Hz).
    magnitude : ndarray, shape (F,)
        Linear magnitude.
    prominence_db : float
        Minimum prominence (dB).
    f_range : (float, float)
        Only peaks inside this band (Hz).
    max_peaks : int
        At most this many, by decreasing prominence.
    """
    sel = (f >= f_range[0]) & (f <= f_range[1])
    if sel.sum() < 3:
        return []
    db = 20.0 * np.log10(np.maximum(np.asarray(magnitude)[sel], 1e-300))
    idx, props = signal.find_peaks(db, prominence=prominence_db)
    order = np.argsort(props["prominences"])[::-1][:max_peaks]
    fs = f[sel]
    mag = np.asarray(magnitude)[sel]
    return [Peak(float(fs[idx[i]]), float(mag[idx[i]]), float(props["prominences"][i]))
            for i in order]


# ---------------------------------------------------------------------------------------------
# One-third-octave bands (IEC 61260-1, base 10)

#: Nominal centre frequencies (Hz) of the base-10 one-third-octave bands 1 Hz ... 80 Hz.
NOMINAL_CENTRES = (1.0, 1.25, 1.6, 2.0, 2.5, 3.15, 4.0, 5.0, 6.3, 8.0, 10.0, 12.5, 16.0, 20.0,
                   25.0, 31.5, 40.0, 50.0, 63.0, 80.0)


def third_octave_bands(f_lo: float = 1.0, f_hi: float = 80.0) -> np.ndarray:
    """Exact base-10 one-third-octave bands with nominal centres in [f_lo, f_hi].

    IEC 61260-1: exact mid-band ``fm = 1000 * 10**(x/10)`` Hz for integer x, edges
    ``fm * 10**(-1/20)`` and ``fm * 10**(+1/20)`` (G = 10**0.3, band = G**(1/3)).

    Returns
    -------
    ndarray, shape (B, 3)
        Columns: exact centre, lower edge, upper edge (Hz).
    """
    x = np.arange(-40, 14)  # 0.1 Hz ... 20 kHz
    fm = 1000.0 * 10.0 ** (x / 10.0)
    keep = (fm >= f_lo * 10 ** (-1 / 20)) & (fm <= f_hi * 10 ** (1 / 20))
    fm = fm[keep]
    return np.column_stack([fm, fm * 10 ** (-1 / 20), fm * 10 ** (1 / 20)])


def band_weights(f: np.ndarray, bands: np.ndarray) -> np.ndarray:
    """Width (Hz) of each PSD bin inside each band, shape (B, F): bin i stands for
    ``[f_i - df/2, f_i + df/2]``, and a bin straddling a band edge is split in proportion to its
    overlap, so adjacent bands partition the power exactly.

    Parameters
    ----------
    f : ndarray, shape (F,)
        Uniformly spaced frequencies (Hz).
    bands : ndarray, shape (B, 3)
        Centre, lower edge, upper edge (Hz) per band.
    """
    df = float(f[1] - f[0])
    lo = f - df / 2
    hi = f + df / 2
    b_lo = np.asarray(bands)[:, 1:2]
    b_hi = np.asarray(bands)[:, 2:3]
    return np.clip(np.minimum(hi[None, :], b_hi) - np.maximum(lo[None, :], b_lo), 0.0, None)


def band_rms(f: np.ndarray, p: np.ndarray, bands: np.ndarray) -> np.ndarray:
    """RMS in each band from a one-sided PSD: ``sqrt(integral of p over the band)`` (bins split
    at the band edges, :func:`band_weights`).

    Parameters
    ----------
    f : ndarray, shape (F,)
        Uniformly spaced frequencies (Hz).
    p : ndarray, shape (F,) or (F, T)
        PSD (unit^2/Hz), or T of them as columns.
    bands : ndarray, shape (B, 3)
        From :func:`third_octave_bands` (centre, lower, upper).

    Returns
    -------
    ndarray, shape (B,) or (B, T)
        Band RMS (unit).
    """
    return np.asarray(np.sqrt(band_weights(f, bands) @ np.asarray(p, dtype=np.float64)))


def band_rms_around(f: np.ndarray, p: np.ndarray, centre_hz: float,
                    half_width_oct: float = 1 / 6) -> float:
    """RMS of a PSD within ``centre * 2**(+-half_width_oct)`` (unit)."""
    band = np.array([[centre_hz, centre_hz * 2 ** -half_width_oct,
                      centre_hz * 2 ** half_width_oct]])
    return float(band_rms(f, p, band)[0])


__all__ = [
    "MIN_AVERAGES", "NOMINAL_CENTRES", "Peak", "TransferEstimate", "asd", "band_rms",
    "band_rms_around", "band_weights", "choose_nperseg", "density_scale", "find_resonances",
    "psd",
    "third_octave_bands", "transfer_h1", "welch_averages", "welch_sums",
]
