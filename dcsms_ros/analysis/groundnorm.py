"""Table 4 with the ground's scatter taken out: a control variate on the recorded ground.

The paper's value is the top stage's band RMS at the Passive resonance, normalised to Passive,
*under the same floor motion*. Two segments of a record see two different stretches of the
floor: their band powers scatter with the floor's own band power (chi-square with a few tens of
degrees of freedom at 24 s) as much as with the control. Every bag records the floor velocity,
so that part of the scatter can be removed without changing what is estimated:

    P_cv = P_top + sum_band w_i |H1_i|**2 (S_common_i - S_ground_i)

with ``P_top`` the segment's band power of the top-stage velocity, ``S_ground`` its floor PSD,
``H1`` its measured floor -> top transmissibility and ``S_common`` the floor PSD common to all
the segments compared (their mean). The correction has expectation zero when the floor is
stationary (``E[S_ground] = S_common``), so ``P_cv`` estimates the same band power; it removes
the part of ``P_top`` the floor's fluctuation explains (the coherent part, ``|H1|**2 S_ground``),
and keeps the rest (table forces, sensor noise, other floor axes). An error of ``H1`` (the
bias of a Welch estimate on a peak narrower than a bin) only enters multiplied by the small
difference ``S_common - S_ground``, so it is of second order. The ratio of two ``P_cv`` is
the normalised value, as the paper defines it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis.modetable import HALF_WIDTH_OCT


def band_power_cv(f: np.ndarray, p_top: np.ndarray, p_ground: np.ndarray, h1: np.ndarray,
                  p_common: np.ndarray, f_r: float) -> float:
    """Ground-corrected band power ((m/s)^2) in ``f_r * 2**(+-1/6)`` (Hz).

    Parameters
    ----------
    f : ndarray, shape (F,)
        Uniform frequencies (Hz).
    p_top, p_ground : ndarray, shape (F,)
        Welch PSDs of the segment's top-stage and floor velocities ((m/s)^2/Hz).
    h1 : ndarray of complex, shape (F,)
        The segment's H1 estimate of floor -> top velocity (dimensionless).
    p_common : ndarray, shape (F,)
        The floor PSD common to the compared segments ((m/s)^2/Hz).
    f_r : float
        Band centre (Hz).
    """
    band = np.array([[f_r, f_r * 2 ** -HALF_WIDTH_OCT, f_r * 2 ** HALF_WIDTH_OCT]])
    w = est.band_weights(f, band)[0]
    return float(w @ p_top + w @ (np.abs(h1) ** 2 * (p_common - p_ground)))


def normalized_cv(segments: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
                  f: np.ndarray, f_r: float, reference: int = 0) -> list[float]:
    """Ground-corrected normalised values (dimensionless) of several segments.

    Parameters
    ----------
    segments : sequence of (p_top, p_ground, h1)
        Per segment, as in :func:`band_power_cv`, all on the grid ``f`` (Hz).
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


__all__ = ["band_power_cv", "normalized_cv"]
