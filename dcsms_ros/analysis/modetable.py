"""The paper's Table 4: stage-N velocity at the reference resonance, normalised to Passive.

Definition (robust against leakage and the exact peak bin): in the reference segment (Passive by
default) the resonance ``f_r`` of an axis is the highest peak of the ASD of the last stage's
velocity v_pN between 1 and 30 Hz. For every segment, ``band_rms`` is the RMS of v_pN within
``f_r * 2**(+-1/6)`` (one-third octave centred on f_r), integrated from a multitaper PSD of the
whole segment (:mod:`.multitaper`: the Welch PSD's kernel is wider than the band and leaks a
sharp reference peak out of it);
``normalized = band_rms / band_rms(reference)`` and ``attenuation_db = -20 log10(normalized)``
(positive: less motion than the reference). The paper measured the velocity at the resonance
with the same excitation in every mode; a band RMS keeps that meaning while averaging over the
few PSD bins a damped peak spreads into.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis.multitaper import band_power
from dcsms_ros.analysis.uncertainty import band_dof

#: Where the reference resonance is searched (Hz): isolation-table modes live here.
RESONANCE_RANGE_HZ = (1.0, 30.0)
HALF_WIDTH_OCT = 1 / 6


def resonance_frequency(f: np.ndarray, asd: np.ndarray) -> float:
    """Frequency (Hz) of the highest ASD peak in :data:`RESONANCE_RANGE_HZ`, between the bins.

    Uses prominent peaks (:func:`estimators.find_resonances`) so a roll-off edge is never taken
    for a resonance; falls back to the ASD maximum in the range if no peak is prominent. The
    peak bin is refined by :func:`refine_peak`, so the band every mode is integrated over does
    not move with the Welch grid (0.12-0.24 Hz: 3-10 % of a 2-4 Hz resonance).
    """
    peaks = est.find_resonances(f, asd, prominence_db=3.0, f_range=RESONANCE_RANGE_HZ,
                                max_peaks=10)
    if peaks:
        i = int(np.argmin(np.abs(f - max(peaks, key=lambda p: p.value).f_hz)))
    else:
        sel = np.flatnonzero((f >= RESONANCE_RANGE_HZ[0]) & (f <= RESONANCE_RANGE_HZ[1]))
        i = int(sel[np.argmax(asd[sel])])
    return refine_peak(f, asd, i)


def refine_peak(f: np.ndarray, asd: np.ndarray, i: int) -> float:
    """The peak frequency (Hz) near bin ``i`` of a uniform grid: the vertex of the parabola
    through the log ASD of bins ``i - 1, i, i + 1`` (exact for a Gaussian-shaped peak, within
    a few % of a bin for a Hann-windowed resonance); bin ``i`` itself at the ends or where the
    three points do not bend down."""
    if i <= 0 or i >= len(f) - 1 or min(asd[i - 1], asd[i], asd[i + 1]) <= 0:
        return float(f[i])
    a, b, c = np.log(asd[i - 1]), np.log(asd[i]), np.log(asd[i + 1])
    bend = a - 2.0 * b + c
    if not bend < 0:
        return float(f[i])
    delta = 0.5 * (a - c) / bend
    return float(f[i] + np.clip(delta, -0.5, 0.5) * (f[i + 1] - f[i]))


def resonance_band_rms(f: np.ndarray, psd: np.ndarray, f_r: float) -> float:
    """RMS (m/s) of a velocity PSD within one-third octave centred on ``f_r`` (Hz)."""
    return est.band_rms_around(f, psd, f_r, HALF_WIDTH_OCT)


def record_band_rms(x: np.ndarray, fs: float, f_r: float) -> float:
    """RMS (m/s) of the velocity record ``x`` (N,) sampled at ``fs`` Hz within one-third octave
    centred on ``f_r`` (Hz): the Table-4 value before normalisation, from the whole record's
    band-passed multitaper PSD (:func:`.multitaper.band_power`)."""
    return float(np.sqrt(band_power(x, fs, f_r * 2.0 ** -HALF_WIDTH_OCT,
                                    f_r * 2.0 ** HALF_WIDTH_OCT)))


def resonance_band_dof(x: np.ndarray, fs: float, f_r: float) -> float:
    """Equivalent degrees of freedom of :func:`resonance_band_rms`'s band power of the record
    ``x`` sampled at ``fs`` Hz (:func:`.uncertainty.band_dof`)."""
    return band_dof(x, fs, f_r * 2.0 ** -HALF_WIDTH_OCT, f_r * 2.0 ** HALF_WIDTH_OCT)


#: ``axes.<a>.estimator`` of a normalised value (:mod:`.table4`), and how the tables name it.
GROUND_CV = "ground_cv"
BAND_RMS = "band_rms"
ESTIMATORS = {
    GROUND_CV: "band RMS of the top stage corrected to the mean recorded floor spectrum "
               "(control variate on the floor; analysis/groundnorm.py)",
    BAND_RMS: "band RMS of the top stage (no floor recorded on a common grid)",
}


def estimator_note(rows: Sequence[dict[str, Any]], axes: Sequence[str]) -> str:
    """One sentence naming the estimators of the rows' values (empty when none is named)."""
    kinds = {r["axes"].get(a, {}).get("estimator") for r in rows for a in axes} - {None}
    if not kinds:
        return ""
    return ("Values: " + "; ".join(ESTIMATORS.get(k, k) for k in sorted(kinds))
            + " (docs/tem.md; the plain ratio is `normalized_plain` in summary.json).")


def normalize(value: float, reference: float) -> tuple[float, float]:
    """``(normalized, attenuation_db)`` of a band RMS against the reference's."""
    if not reference > 0:
        return float("nan"), float("nan")
    ratio = value / reference
    return ratio, float(-20 * np.log10(ratio)) + 0.0 if ratio > 0 else float("inf")


def format_table(rows: Sequence[dict[str, Any]], axes: Sequence[str]) -> str:
    """Plain-text mode table: one row per segment, ``normalized``, its interval and the
    attenuation (dB, -20 log10 normalized: positive where the mode attenuates) per axis.

    Parameters
    ----------
    rows : sequence of dict
        ``{"mode": str, "axes": {axis: {"normalized": float, "attenuation_db": float,
        "normalized_ci": [lo, hi] (optional)}}}``.
    axes : sequence of str
        Axis names in column order.
    """
    head = f"{'mode':<10}" + "".join(f"{a.upper() + ' norm':>12}{'95 % CI':>16}{'att. dB':>9}"
                                     for a in axes)
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = []
        for a in axes:
            ax = r["axes"].get(a, {})
            n, db = ax.get("normalized"), ax.get("attenuation_db")
            cells.append(f"{_num(n, '.3f'):>12}{interval(ax.get('normalized_ci')):>16}"
                         f"{_num(db, '+.1f'):>9}")
        flag = "  UNSTABLE" if r.get("stability", {}).get("unstable") else ""
        lines.append(f"{r['mode']:<10}" + "".join(cells) + flag)
    return "\n".join(lines)


def interval(ci: Sequence[float] | None) -> str:
    """``[lo, hi]`` of a normalised value's interval (``-`` when there is none)."""
    if ci is None or not all(np.isfinite(c) for c in ci):
        return "-"
    return f"[{ci[0]:.3f}, {ci[1]:.3f}]"


def _num(x: float | None, fmt: str) -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, fmt)


__all__ = [
    "BAND_RMS",
    "ESTIMATORS",
    "GROUND_CV",
    "HALF_WIDTH_OCT",
    "RESONANCE_RANGE_HZ",
    "estimator_note",
    "format_table",
    "interval",
    "normalize",
    "record_band_rms",
    "refine_peak",
    "resonance_band_dof",
    "resonance_band_rms",
    "resonance_frequency",
]
