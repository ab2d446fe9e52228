"""Table 4 with the ground's scatter taken out: a control variate on the recorded ground.

The paper's value is the top stage's band RMS at the Passive resonance, normalised to Passive,
*under the same floor motion*. Two segments of a record see two different stretches of the
floor: their band powers scatter with the floor's own band power (chi-square with a few tens of
degrees of freedom at 24 s) as much as with the control. Every bag records the floor velocity,
so that part of the scatter can be removed without changing what is estimated:

    P_cv = P_top + sum_band w_i |H1_i|**2 (S_common_i - S_ground_i)

with ``P_top`` the segment's band power of the top-stage velocity (from the whole record's
multitaper PSD, :mod:`.multitaper`, which does not leak a sharp peak out of the band), ``S_ground``
its floor Welch PSD, ``H1`` its measured floor -> top transmissibility and ``S_common`` the floor
PSD common to all the segments compared (their mean). The correction has expectation zero when the
floor is stationary (``E[S_ground] = S_common``), so ``P_cv`` estimates the same band power; it
removes the part of ``P_top`` the floor's fluctuation explains (the coherent part, ``|H1|**2
S_ground``), and keeps the rest (table forces, sensor noise, other floor axes). An error of ``H1``
(the bias of a Welch estimate on a peak narrower than a bin) only enters multiplied by the small
difference ``S_common - S_ground``, so it is of second order. The ratio of two ``P_cv`` is the
normalised value, as the paper defines it.

Since ``|H1|**2 S_ground = coherence * S_top`` bin by bin, ``P_cv`` is also, up to the
difference between the multitaper and the Welch band power of the top stage,
``sum_band w_i (|H1_i|**2 S_common_i + (1 - coherence_i) S_top_i)``: the floor-driven part under
the common floor plus the part the floor does not explain (table forces, sensor noise).

Its interval: the plain band power's degrees of freedom (:func:`.uncertainty.band_dof`,
calibrated against the batch engine) divided by :func:`variance_ratio`, the reduction of the
relative variance the correction achieves, read from the record's floor -> top coherence.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy import signal

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis.modetable import HALF_WIDTH_OCT


def _band(f: np.ndarray, f_r: float) -> np.ndarray:
    """Width (Hz) of each bin of ``f`` inside one-third octave around ``f_r`` (Hz), shape (F,)."""
    band = np.array([[f_r, f_r * 2 ** -HALF_WIDTH_OCT, f_r * 2 ** HALF_WIDTH_OCT]])
    return np.asarray(est.band_weights(f, band)[0])


def band_power_cv(f: np.ndarray, top_power: float, p_ground: np.ndarray, h1: np.ndarray,
                  p_common: np.ndarray, f_r: float) -> float:
    """Ground-corrected band power ((m/s)^2) in ``f_r * 2**(+-1/6)`` (Hz).

    Parameters
    ----------
    f : ndarray, shape (F,)
        Uniform frequencies (Hz).
    top_power : float
        The segment's band power of the top-stage velocity ((m/s)^2), from the whole record
        (:func:`.modetable.record_band_rms` squared).
    p_ground : ndarray, shape (F,)
        Welch PSD of the segment's floor velocity ((m/s)^2/Hz).
    h1 : ndarray of complex, shape (F,)
        The segment's H1 estimate of floor -> top velocity (dimensionless).
    p_common : ndarray, shape (F,)
        The floor PSD common to the compared segments ((m/s)^2/Hz).
    f_r : float
        Band centre (Hz).
    """
    w = _band(f, f_r)
    return float(top_power + w @ (np.abs(h1) ** 2 * (p_common - p_ground)))


def normalized_cv(segments: Sequence[tuple[float, np.ndarray, np.ndarray]],
                  f: np.ndarray, f_r: float, reference: int = 0) -> list[float]:
    """Ground-corrected normalised values (dimensionless) of several segments.

    Parameters
    ----------
    segments : sequence of (top_power, p_ground, h1)
        Per segment, as in :func:`band_power_cv`, the spectra on the grid ``f`` (Hz).
    f : ndarray, shape (F,)
        Frequencies (Hz).
    f_r : float
        The reference resonance (Hz).
    reference : int
        Index of the reference segment.
    """
    common = np.mean([g for _, g, _ in segments], axis=0)
    powers = [band_power_cv(f, top, g, h, common, f_r) for top, g, h in segments]
    base = powers[reference]
    return [float(np.sqrt(max(p, 0.0) / base)) if base > 0 else float("nan") for p in powers]


def segment_spectra(x: np.ndarray, fs: float, nperseg: int,
                    rows: np.ndarray | None = None, block: int = 256) -> np.ndarray:
    """The Fourier transforms of the Welch segments :func:`.estimators.psd` averages (Hann,
    half overlap, mean removed) of ``x`` (N,) sampled at ``fs`` Hz, scaled so that
    ``|X|**2`` is the segment's one-sided density (unit^2/Hz), shape (F, K); with ``rows`` (a
    boolean mask of the F bins) only those bins. ``block`` segments are transformed at a time,
    so an hour's record needs ~``block`` segments of work arrays, not all of them (~0.5 GB)."""
    x = np.asarray(x)  # each block in float64, not the whole record
    hop = nperseg - nperseg // 2
    k = 1 + (x.shape[0] - nperseg) // hop if x.shape[0] >= nperseg else 0
    scale = np.full(nperseg // 2 + 1, np.sqrt(2.0))
    scale[0] = 1.0
    if nperseg % 2 == 0:
        scale[-1] = 1.0
    keep = np.ones(scale.size, bool) if rows is None else np.asarray(rows, bool)
    out = []
    for s0 in range(0, k, block):
        m = min(block, k - s0)
        seg = np.asarray(x[s0 * hop:(s0 + m - 1) * hop + nperseg], dtype=np.float64)
        _, _, z = signal.stft(seg, fs, window="hann", nperseg=nperseg, noverlap=nperseg // 2,
                              detrend="constant", boundary=None, padded=False, scaling="psd")
        out.append(z[keep] * scale[keep, None])
    return (np.concatenate(out, axis=1) if out
            else np.zeros((int(keep.sum()), 0), dtype=np.complex128))


def variance_ratio(f: np.ndarray, top: np.ndarray, ground: np.ndarray, f_r: float, fs: float,
                   nperseg: int) -> float:
    """Relative variance of the corrected band power over that of the plain one (dimensionless),
    from the record's floor -> top coherence.

    Per bin, with the top velocity ``y = H g + n`` (``n`` the part the floor does not drive:
    table forces, sensor noise), the plain power ``|y|**2`` has variance ``(S_h + S_n)**2`` and
    the corrected one ``S_n**2 + 2 S_h S_n`` (first order in the error of ``H1``, which the
    record's own ``H1`` cancels), ``S_h = |H|**2 S_ground``: their ratio is ``1 - coh**2``
    with ``coh = S_h / (S_h + S_n)`` the magnitude-squared coherence. The band's ratio weights
    each bin by its share of the band power's variance (``(w S_top)**2``). ``4 coh (1 - coh) /
    K`` is added for what a first-order argument leaves out: the multitaper band power and the
    Welch correction see the floor's fluctuation through different windows, and ``coh`` itself
    comes from ``K`` segments. On the analytic case of ``test_groundnorm.py`` this errs on the
    safe side (0.40 for a measured 0.32 when the floor explains 90 % of the band).

    Read from averaged spectra, the ratio scatters little from record to record (s.d. of its
    logarithm 0.16-0.23 there); an earlier estimate from the spread of the ``K`` Welch
    segments' band powers scattered by 0.6-0.9 and gave 1 record in 20 an interval 3-6 times
    too narrow in variance (TEM seed 104: r = 0.105 where other seeds read 0.2-1.1).

    Parameters
    ----------
    f : ndarray, shape (F,)
        The Welch grid of ``nperseg`` samples at ``fs`` (Hz).
    top, ground : ndarray, shape (N,)
        The segment's top-stage and floor velocities (m/s).
    f_r : float
        Band centre (Hz).
    fs : float
        Sample rate (Hz).
    nperseg : int
        Welch segment length (samples).

    Returns
    -------
    float
        In (0, 1 + 1/K]; 1 where the band is silent.
    """
    w = _band(f, f_r)
    sel = w > 0
    y = segment_spectra(top, fs, nperseg, sel)
    g = segment_spectra(ground, fs, nperseg, sel)
    k = y.shape[1]
    syy = np.mean(np.abs(y) ** 2, axis=1)
    sgg = np.mean(np.abs(g) ** 2, axis=1)
    sgy = np.mean(np.conj(g) * y, axis=1)
    var = (w[sel] * syy) ** 2  # each bin's share of the plain band power's variance
    if k < 1 or not np.sum(var) > 0:
        return 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        coh = np.nan_to_num(np.clip(np.abs(sgy) ** 2 / (sgg * syy), 0.0, 1.0))
    per_bin = 1.0 - coh ** 2 + 4.0 * coh * (1.0 - coh) / k
    return float(var @ per_bin / np.sum(var))


__all__ = ["band_power_cv", "normalized_cv", "segment_spectra",
           "variance_ratio"]
