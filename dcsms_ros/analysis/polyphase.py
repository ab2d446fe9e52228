"""Rational-rate resampling on numpy alone: a Kaiser-window FIR run as a polyphase filter.

What ``scipy.signal.resample_poly(x, up, down, axis=0, padtype="line")`` computes (filter
design, group-delay alignment, the signal extended along the line through its first and
last samples), written here so that the plant node, which may replay a recorded ground,
does not import ``scipy.signal`` (~0.45 s of CPU at start-up). The products are summed in
scipy's order; the taps agree with scipy's to ~1e-17 (numpy's Bessel I0 in the window), so
the output agrees to ~1e-15 of its scale (``test/analysis/test_polyphase.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: Kaiser window shape parameter of the anti-aliasing filter.
KAISER_BETA = 5.0
#: Half length of the filter, in samples of the slower of the two rates.
HALF_TAPS_PER_RATE = 10
#: Output rows computed at a time (bounds the gathered taps x samples block).
CHUNK = 8192


def lowpass_taps(up: int, down: int) -> Array:
    """The anti-aliasing FIR of an ``up/down`` resampler: windowed sinc with its cutoff at
    the lower Nyquist frequency, unit gain at DC, times ``up`` (the zero-stuffing loss),
    shape (2 * 10 * max(up, down) + 1,)."""
    rate = max(up, down)
    n = 2 * HALF_TAPS_PER_RATE * rate + 1
    cutoff = 1.0 / rate  # of the upsampled Nyquist
    m = np.arange(0, n, dtype=np.float64) - 0.5 * (n - 1)
    h = cutoff * np.sinc(cutoff * m) * np.kaiser(n, KAISER_BETA)
    return np.asarray(h / np.sum(h) * up, dtype=np.float64)


def resample_poly(x: ArrayLike, up: int, down: int) -> Array:
    """Resample ``x`` (K, n) along axis 0 by ``up/down`` (integers >= 1).

    Returns
    -------
    ndarray, shape (ceil(K * up / down), n)
        Output sample m sits at input time ``m * down / up`` (no delay); beyond the record the
        input continues on the line through its first and last samples.
    """
    xs = np.asarray(x, dtype=np.float64)
    g = math.gcd(int(up), int(down))
    up, down = int(up) // g, int(down) // g
    if up == down == 1:
        return xs.copy()
    k_in = xs.shape[0]
    if k_in < 2:
        raise ValueError("resample_poly: need at least 2 samples")
    h = lowpass_taps(up, down)
    half = (h.size - 1) // 2
    n_out = -(-k_in * up // down)
    per_phase = -(-h.size // up)
    # phase p holds h[p + k*up] for k = per_phase-1 .. 0, so that its taps meet the input
    # oldest first, the order scipy accumulates in
    padded = np.concatenate([h, np.zeros(per_phase * up - h.size)])
    phases = padded.reshape(per_phase, up).T[:, ::-1]
    slope = (xs[-1] - xs[0]) / (k_in - 1)
    out = np.empty((n_out, xs.shape[1]))
    for start in range(0, n_out, CHUNK):
        m = np.arange(start, min(start + CHUNK, n_out))
        pos = m * down + half  # in upsampled samples, the filter centred on the output
        newest, phase = pos // up, pos % up
        acc = np.zeros((m.size, xs.shape[1]))
        for i in range(per_phase):
            idx = newest - (per_phase - 1) + i
            acc += _extended(xs, idx, slope) * phases[phase, i][:, None]
        out[start:start + m.size] = acc
    return out


def _extended(xs: Array, idx: NDArray[np.int64], slope: Array) -> Array:
    """Rows ``idx`` of ``xs``, continued on the line through the first and last rows."""
    k = xs.shape[0]
    rows = xs[np.clip(idx, 0, k - 1)].copy()
    lo, hi = idx < 0, idx >= k
    if lo.any():
        rows[lo] = xs[0] + idx[lo, None].astype(np.float64) * slope
    if hi.any():
        rows[hi] = xs[-1] + (idx[hi, None] - k + 1).astype(np.float64) * slope
    return rows


__all__ = ["CHUNK", "HALF_TAPS_PER_RATE", "KAISER_BETA", "lowpass_taps", "resample_poly"]
