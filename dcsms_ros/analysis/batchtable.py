"""Table 4 of batch runs held in memory, with the definition ``dcsms analyze`` applies to a bag:
the measured (decoupled) top-stage velocity after the settle time, its Welch PSD with the
analysis's segment length for the Passive resonance, and the one-third-octave band RMS of the
whole record's multitaper PSD."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import modetable
from dcsms_ros.analysis.predict import TRANSLATIONS
from dcsms_ros.analysis.segments import SETTLE_S
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.simresult import SimResult


def table4_of_runs(runs: Mapping[Mode, SimResult], axes: Sequence[str],
                   reference: Mode = Mode.PASSIVE, settle_s: float = SETTLE_S
                   ) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """(resonance Hz per axis, normalised value per mode label and axis) of one run per mode.

    Raises
    ------
    KeyError
        If ``runs`` has no run of the reference mode.
    """
    records, fs = {}, {}
    for m, res in runs.items():
        fs[m] = res.cfg.plant.rate_hz
        n, dof = res.cfg.plant.num_stages, res.cfg.plant.dof
        v = res.velocity[int(round(settle_s * fs[m])):, n]
        cols = [0] if dof == 1 else [TRANSLATIONS.index(a) for a in axes]
        records[m] = [np.ascontiguousarray(v[:, c]) for c in cols]
    f_r, base = {}, {}
    for j, a in enumerate(axes):
        x, rate = records[reference][j], fs[reference]
        f, p = est.psd(x, rate, est.choose_nperseg(rate, x.shape[0]))
        f_r[a] = modetable.resonance_frequency(f, np.sqrt(p))
        base[a] = modetable.record_band_rms(x, rate, f_r[a])
    values = {m.label: {a: modetable.record_band_rms(records[m][j], fs[m], f_r[a]) / base[a]
                        for j, a in enumerate(axes)} for m in runs}
    return f_r, values


__all__ = ["table4_of_runs"]
