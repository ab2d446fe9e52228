"""Is a recorded segment unstable? A growing envelope, told apart from stationary scatter.

The velocity's RMS is taken over consecutive windows; the envelope's growth rate is the slope
of log RMS against time (least squares), and the growth over the segment the ratio of the RMS
in its last quarter to its first. A stationary record, even a narrow-band one, keeps those
ratios near 1 (a quarter of a 12 s segment holds a few hundred cycles at the table modes); an
unstable loop multiplies them. The segment is called unstable when the RMS of every quarter is
above the one before, the last quarter's is at least :data:`GROWTH_FACTOR` times the first's,
and the growth does not slow down: the last quarter-to-quarter step in ln RMS is at least
:data:`KEEPS_GROWING` of the first. An exponential keeps (or, out of the noise floor, gains)
its pace; a build-up towards a new stationary level after a switch, or from rest at the start
of a run, loses it (a lightly damped 0.5 Hz mode of a TEM takes ~20 s to settle).

A record whose power sits in content slower than the record resolves breaks the premise
above: each quarter then holds less than one cycle of it, and its mean square is close to one
random draw. The TEM fit's decoupled stage velocities are such records: the geophones'
self-noise, amplified by their extension to 0.02 Hz, is in the reading (in DFBC+FFC the model
puts 4.6 um/s of the stage-1 z reading below 0.2 Hz, where the block itself moves 0.03 um/s,
against 0.35 um/s at 0.2-1 Hz), and their envelopes "grew" 3-10x within a 60 s segment with no
change in the loop. :func:`resolved_factor` is the same growth factor
with that content removed (a high-pass at one cycle per quarter): a growth that it does not
confirm lies in content that the record cannot tell from a stationary wander.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import signal

#: Last-quarter over first-quarter RMS that calls a monotone envelope unstable.
GROWTH_FACTOR = 3.0
#: Window of the envelope's RMS, s (at most a sixteenth of the record).
WINDOW_S = 0.5
#: Last over first quarter-to-quarter growth step (ln RMS) that still counts as exponential.
KEEPS_GROWING = 0.7
#: Order of the high-pass of :func:`resolved_factor`.
RESOLVED_ORDER = 2


@dataclass(frozen=True)
class Envelope:
    """Envelope of one signal: ``rate_per_s`` (slope of ln RMS, 1/s), ``factor`` (last over
    first quarter RMS), ``growing`` (the verdict, module docstring), ``quarter_s`` (the
    shortest quarter's length, s)."""

    rate_per_s: float
    factor: float
    growing: bool
    quarter_s: float


def envelope(x: NDArray[np.floating], fs: float) -> Envelope | None:
    """Growth of ``x`` (K,) sampled at ``fs`` (Hz); None when too short to judge (< 16
    windows) or all zero."""
    v = np.asarray(x, dtype=np.float64)
    w = max(1, min(int(WINDOW_S * fs), v.size // 16))
    n = v.size // w
    if n < 16:
        return None
    r = np.sqrt(np.mean(v[: n * w].reshape(n, w) ** 2, axis=1))
    if not np.all(r > 0):
        return None
    t = (np.arange(n) + 0.5) * w / fs
    rate = float(np.polyfit(t, np.log(r), 1)[0])
    quarters = np.array_split(r, 4)
    q = [float(np.sqrt(np.mean(c ** 2))) for c in quarters]
    factor = q[-1] / q[0]
    steps = [math.log(b / a) for a, b in itertools.pairwise(q)]
    growing = (all(d > 0 for d in steps) and factor >= GROWTH_FACTOR
               and steps[-1] >= KEEPS_GROWING * steps[0])
    return Envelope(rate, factor, growing, min(c.size for c in quarters) * w / fs)


def resolved_factor(x: NDArray[np.floating], fs: float, env: Envelope) -> float:
    """Last over first quarter RMS of ``x`` (K,) sampled at ``fs`` (Hz) without its content
    slower than one cycle per quarter of ``env`` (second-order Butterworth high-pass at
    ``1 / env.quarter_s`` Hz, run forwards and backwards: no phase, no start-up ramp); nan when
    too short to judge."""
    v = np.asarray(x, dtype=np.float64)
    corner = 1.0 / env.quarter_s
    if not 0.0 < corner < fs / 2.0:
        return float("nan")
    sos = signal.butter(RESOLVED_ORDER, corner, "highpass", fs=fs, output="sos")
    high = envelope(signal.sosfiltfilt(sos, v - v.mean()), fs)
    return float("nan") if high is None else high.factor


__all__ = ["GROWTH_FACTOR", "KEEPS_GROWING", "RESOLVED_ORDER", "WINDOW_S", "Envelope",
           "envelope", "resolved_factor"]
