"""Band power of a whole record without the Welch segments' leakage: a multitaper spectrum.

Table 4 integrates the top stage's PSD over one third of an octave around a sharp resonance
(the TEM's Z Passive peak at 1.9 Hz: band 0.44 Hz wide). A Welch PSD with 24 s records uses
4.1 s Hann segments: its kernel (+-2 bins of 0.244 Hz) is wider than the band, so the sharp
Passive peak leaks out of the band while a damped mode's broad spectrum does not, and every
normalised value divided by the Passive reference comes out high (+0.16 in ln for TEM Z DFBC
at 24 s, measured over 80 seeds; docs/tem.md). Discrete prolate spheroidal (Slepian) tapers
spanning the whole record concentrate each kernel within +-``NW / T`` Hz (0.083 Hz at 24 s)
while using every sample about evenly, so the band power keeps the full record's degrees of
freedom (:func:`.uncertainty.band_dof` still applies) and loses no power across the band
edges. The Welch PSD stays for the resonance search, the plots and the transfer functions.

The Slepian kernel's far sidelobes are small but not zero, and a measured velocity carries far
more power below 1 Hz (the geophones' extended low-frequency noise, the rocking modes) than a
well-controlled mode has in the band: a whole-record spectrum of the raw record put 2-3x too
much power into TEM X DFBC's band (+0.75 in ln over 30 seeds at 24 s). :func:`band_power`
therefore band-passes the record first (zero phase, an octave outside the band on each side)
and divides the filter's known gain back out.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import signal
from scipy.signal.windows import dpss

from dcsms_ros.analysis import estimators as est

#: Time-half-bandwidth product: the kernel spans +-NW / T Hz; 2 keeps it well inside a
#: third-octave band at 2 Hz for records of 12 s and more.
NW = 2.0
#: Tapers averaged (2 NW - 1: each concentrates more than 99.9 % of its power within +-NW / T).
TAPERS = 3
#: Butterworth order of the band-pass applied (forwards and backwards) before the spectrum,
#: and how far outside the band its corners sit (octaves): the gain in the band is then within
#: 1e-4 of 1 and is divided out exactly.
PREFILTER_ORDER = 4
PREFILTER_MARGIN_OCT = 1.0
#: After the band-pass the record is kept at a rate of at least this many times the upper
#: corner (every q-th sample): what folds into the band then comes from 7 or more times the
#: corner, where the filter has taken it down by 140 dB and more, and the spectrum of an hour at
#: 2 kHz is ~160,000 samples instead of 7.2 million (its tapers and FFT took ~1.5 GB).
KEEP_RATE_FACTOR = 8.0


@lru_cache(maxsize=8)
def _tapers(n: int, nw: float, k: int) -> np.ndarray:
    """(k, n) Slepian tapers, each of unit energy (sum of squares 1)."""
    return np.atleast_2d(np.asarray(dpss(n, nw, k), dtype=np.float64))


def psd_multitaper(x: np.ndarray, fs: float, nw: float = NW,
                   tapers: int = TAPERS) -> tuple[np.ndarray, np.ndarray]:
    """One-sided multitaper PSD of a whole record (unit^2/Hz).

    Parameters
    ----------
    x : ndarray, shape (N,)
        The record (any unit; its mean is removed).
    fs : float
        Sample rate (Hz).
    nw : float
        Time-half-bandwidth product (dimensionless): resolution +-``nw * fs / N`` Hz.
    tapers : int
        Number of Slepian tapers averaged.

    Returns
    -------
    f : ndarray, shape (N // 2 + 1,)
        Frequencies (Hz), spacing ``fs / N``.
    p : ndarray, shape (N // 2 + 1,)
        PSD (unit^2/Hz); its integral is the record's variance.
    """
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    w = _tapers(n, float(nw), int(tapers))
    spec = np.fft.rfft(w * (x - x.mean())[None, :], axis=1)
    p = np.mean(np.abs(spec) ** 2, axis=0) / fs
    p[1:] *= 2.0
    if n % 2 == 0:
        p[-1] /= 2.0
    return np.fft.rfftfreq(n, 1.0 / fs), p


def band_power(x: np.ndarray, fs: float, f_lo: float, f_hi: float) -> float:
    """Power of the record ``x`` (N,) within ``[f_lo, f_hi]`` (Hz), unit^2.

    The record is band-passed an octave outside the band (zero phase), kept at
    :data:`KEEP_RATE_FACTOR` times the upper corner at least, its multitaper PSD
    (:func:`psd_multitaper`) divided by the filter's power gain and integrated over the band
    (bins split at the edges, :func:`.estimators.band_weights`).

    Parameters
    ----------
    x : ndarray, shape (N,)
        The record (e.g. a velocity, m/s), sampled at ``fs`` Hz.
    fs : float
        Sample rate (Hz).
    f_lo, f_hi : float
        Band edges (Hz), ``0 < f_lo < f_hi < fs / 2``.
    """
    lo = f_lo * 2.0 ** -PREFILTER_MARGIN_OCT
    hi = min(f_hi * 2.0 ** PREFILTER_MARGIN_OCT, 0.45 * fs)
    sos = signal.butter(PREFILTER_ORDER, [lo, hi], btype="bandpass", fs=fs, output="sos")
    x = np.asarray(x, dtype=np.float64)
    # padding of three periods of the lower corner (odd extension): a slow drift's step at the
    # record's ends would otherwise ring through the filter into the band
    y = signal.sosfiltfilt(sos, x, padlen=min(int(3.0 * fs / lo), x.shape[0] - 1))
    q = max(1, int(fs / (KEEP_RATE_FACTOR * hi)))
    y, fs_kept = y[::q].copy(), fs / q  # a copy: the full-rate record is freed
    f, p = psd_multitaper(y, fs_kept)
    df = fs_kept / y.shape[0]
    sel = (f >= f_lo - df) & (f <= f_hi + df)
    gain = np.abs(signal.sosfreqz(sos, worN=f[sel], fs=fs)[1]) ** 4  # filtfilt: |H|^2, power
    band = np.array([[np.sqrt(f_lo * f_hi), f_lo, f_hi]])
    w = est.band_weights(f[sel], band)[0] if sel.sum() > 1 else np.zeros(sel.sum())
    return float(w @ (p[sel] / gain))


__all__ = ["KEEP_RATE_FACTOR", "NW", "PREFILTER_MARGIN_OCT", "PREFILTER_ORDER", "TAPERS",
           "band_power", "psd_multitaper"]
