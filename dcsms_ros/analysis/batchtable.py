"""Table 4 of batch runs held in memory, with the definition ``dcsms analyze`` applies to a bag:
the measured (decoupled) top-stage velocity after the settle time, its Welch PSD with the
analysis's segment length, the Passive resonance and the one-third-octave band RMS."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import modetable
from dcsms_ros.analysis.predict import TRANSLATIONS
from dcsms_ros.analysis.segments import SETTLE_S
from dcsms_ros.core.engine import SimResult
from dcsms_ros.core.modes import Mode


def table4_of_runs(runs: Mapping[Mode, SimResult], axes: Sequence[str],
                   reference: Mode = Mode.PASSIVE, settle_s: float = SETTLE_S
                   ) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """(resonance Hz per axis, normalised value per mode label and axis) of one run per mode.

    Raises
    ------
    KeyError
        If ``runs`` has no run of the reference mode.
    """
    spectra = {}
    for m, res in runs.items():
        fs = res.cfg.plant.rate_hz
        n, dof = res.cfg.plant.num_stages, res.cfg.plant.dof
        v = res.velocity[int(round(settle_s * fs)):, n]
        cols = [0] if dof == 1 else [TRANSLATIONS.index(a) for a in axes]
        nper = est.choose_nperseg(fs, v.shape[0])
        spectra[m] = [est.psd(np.ascontiguousarray(v[:, c]), fs, nper) for c in cols]
    f_r, base = {}, {}
    for j, a in enumerate(axes):
        f, p = spectra[reference][j]
        f_r[a] = modetable.resonance_frequency(f, np.sqrt(p))
        base[a] = modetable.resonance_band_rms(f, p, f_r[a])
    values = {m.label: {a: modetable.resonance_band_rms(*spectra[m][j], f_r[a]) / base[a]
                        for j, a in enumerate(axes)} for m in runs}
    return f_r, values


__all__ = ["table4_of_runs"]
