"""Generic vibration criteria VC-A ... VC-G for vibration-sensitive equipment.

Source: C. G. Gordon, "Generic vibration criteria for vibration-sensitive equipment", Proc. SPIE
1619 (1991) and 3786 (1999); standardised in IEST-RP-CC012 ("Considerations in Clean Room
Design"). Summaries checked: Crystal Instruments, "Vibration Criteria for Facilities with
Sensitive Equipment" (https://www.crystalinstruments.com/vibration-criteria-for-facilities-
with-sensitive-equipment), Daeil Systems, "Generic Vibration Criteria"
(https://www.daeilsys.com/support/technical-notes/generic-vibration-criteria/) and
motioncontroltips.com "What are vibration criteria and VC curves?".

Each criterion is a limit on the RMS velocity in every one-third-octave band:

===== ================ ==========================================================
curve RMS velocity     note
===== ================ ==========================================================
VC-A  50 um/s          8-80 Hz; constant acceleration 260 ug from 4 to 8 Hz
VC-B  25 um/s          8-80 Hz; constant acceleration 130 ug from 4 to 8 Hz
VC-C  12.5 um/s        1-80 Hz, flat
VC-D  6.25 um/s        1-80 Hz, flat
VC-E  3.12 um/s        1-80 Hz, flat
VC-F  1.56 um/s        1-80 Hz, flat
VC-G  0.78 um/s        1-80 Hz, flat
===== ================ ==========================================================

The published VC-A/VC-B curves start at 4 Hz. Below 4 Hz this module holds them at their 4 Hz
value (~101 and ~51 um/s) instead of extending the constant-acceleration line, which would
allow ever larger velocities at low frequency; this is the conservative reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

G0 = 9.80665  # m/s^2 per g


@dataclass(frozen=True)
class Criterion:
    """One VC curve: flat velocity limit (m/s) above ``accel_until_hz``, constant acceleration
    (m/s^2) from 4 Hz up to it (None: flat everywhere)."""

    name: str
    velocity_mps: float
    accel_mps2: float | None = None
    accel_until_hz: float = 8.0

    def limit(self, f_hz: np.ndarray) -> np.ndarray:
        """Band RMS velocity limit (m/s) at one-third-octave centres ``f_hz`` (B,)."""
        f = np.asarray(f_hz, dtype=np.float64)
        lim = np.full(f.shape, self.velocity_mps)
        if self.accel_mps2 is not None:
            low = f < self.accel_until_hz
            lim[low] = self.accel_mps2 / (2 * np.pi * np.maximum(f[low], 4.0))
        return lim


#: Most lenient first.
CRITERIA: tuple[Criterion, ...] = (
    Criterion("VC-A", 50e-6, 260e-6 * G0),
    Criterion("VC-B", 25e-6, 130e-6 * G0),
    Criterion("VC-C", 12.5e-6),
    Criterion("VC-D", 6.25e-6),
    Criterion("VC-E", 3.12e-6),
    Criterion("VC-F", 1.56e-6),
    Criterion("VC-G", 0.78e-6),
)
#: Band range (Hz) over which the criteria apply.
F_RANGE = (1.0, 80.0)


@dataclass
class Verdict:
    """Result of :func:`evaluate`.

    Attributes
    ----------
    best : str or None
        The most stringent criterion met in every band (None: not even VC-A).
    margin_db : float
        20 log10(limit / level) of ``best`` in its worst band (>= 0), or of VC-A when no
        criterion is met (< 0).
    worst_band_hz : float
        Centre (Hz) of the band that decides it.
    """

    best: str | None
    margin_db: float
    worst_band_hz: float


def evaluate(centres_hz: np.ndarray, rms_mps: np.ndarray) -> Verdict:
    """The most stringent VC criterion met by a one-third-octave velocity spectrum.

    Parameters
    ----------
    centres_hz : ndarray, shape (B,)
        Band centre frequencies (Hz); bands outside 1-80 Hz are ignored.
    rms_mps : ndarray, shape (B,)
        Band RMS velocity (m/s).
    """
    c = np.asarray(centres_hz, dtype=np.float64)
    v = np.asarray(rms_mps, dtype=np.float64)
    sel = (c >= F_RANGE[0] * 0.99) & (c <= F_RANGE[1] * 1.01)
    c, v = c[sel], v[sel]
    if c.size == 0:
        raise ValueError("no one-third-octave bands between 1 and 80 Hz")
    best: Verdict | None = None
    for crit in CRITERIA:
        with np.errstate(divide="ignore"):
            margin = 20 * np.log10(crit.limit(c) / np.maximum(v, 1e-30))
        j = int(np.argmin(margin))
        if margin[j] >= 0:
            best = Verdict(crit.name, float(margin[j]), float(c[j]))
        elif best is None:
            return Verdict(None, float(margin[j]), float(c[j]))
        else:
            break
    assert best is not None
    return best


__all__ = ["CRITERIA", "F_RANGE", "Criterion", "Verdict", "evaluate"]
