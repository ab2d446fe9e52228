"""The paper's Table 4 predicted from the model of the loop that runs (no simulation).

Same definition as ``dcsms analyze`` (:mod:`.modetable`), applied to the PSD the model predicts
for the top stage's decoupled velocity (what a rig records on ``/dcsms/velocity/stageN`` and
what the analysis reads) under the configured ground, table-force and geophone-noise spectra
(:mod:`dcsms_ros.core.spectra`): the reference resonance is the highest prominent peak of the
reference mode's ASD in :data:`.modetable.RESONANCE_RANGE_HZ`, and each mode's value is its band
RMS within one-third octave around it, divided by the reference's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.analysis import modetable
from dcsms_ros.analysis.estimators import band_rms_around
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.loop_model import LoopModel, Response, loop_model
from dcsms_ros.core.model import axis_names
from dcsms_ros.core.modes import ALL_MODES, Mode
from dcsms_ros.core.spectra import shaped

Array = NDArray[np.float64]

#: Grid step of the resonance search (Hz) and of the band integration (fraction of the band).
SEARCH_STEP_HZ = 0.01
BAND_POINTS = 1201
#: Axes of the table: z in 1dof, the translations in 6dof.
TRANSLATIONS = ("x", "y", "z")


@dataclass
class Table4:
    """Predicted Table 4: ``values[mode label][axis]`` normalised band RMS (inf: unstable)."""

    reference: str
    resonance_hz: dict[str, float]
    band_rms_mps: dict[str, dict[str, float]] = field(default_factory=dict)
    values: dict[str, dict[str, float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, object]:
        """``{"reference": ..., "resonance_hz": {axis: Hz}, "modes": {label: {axis: x}}}``."""
        return {"reference": self.reference, "resonance_hz": self.resonance_hz,
                "modes": self.values}


def table_axes(cfg: SystemConfig) -> list[str]:
    """Axes the table reports: ``z`` in 1dof, ``x y z`` in 6dof."""
    return ["z"] if cfg.plant.dof == 1 else list(TRANSLATIONS)


class TopVelocity:
    """PSD of the top stage's decoupled velocity along the table axes, from a shaped model."""

    def __init__(self, cfg: SystemConfig, mode: Mode) -> None:
        model: LoopModel = shaped(cfg, loop_model(cfg, mode))
        dof, n = cfg.plant.dof, cfg.plant.num_stages
        names = axis_names(dof)
        rows = [model.outputs["velocity"].start + n * dof + names.index(a)
                for a in table_axes(cfg)]
        self.stable = bool(np.max(np.abs(np.linalg.eigvals(model.a)), initial=0.0) < 1.0)
        self._resp = Response(model.select(slice(0, model.b.shape[1]), rows))
        self._two_dt = 2.0 * model.dt

    def psd(self, f_hz: Array) -> Array:
        """One-sided PSD, (m/s)^2/Hz, shape (F, n_axes)."""
        h = self._resp(f_hz)
        return np.asarray(self._two_dt * np.sum(np.abs(h) ** 2, axis=2), dtype=np.float64)


def band_rms(top: TopVelocity, f_r: float, points: int = BAND_POINTS) -> Array:
    """Band RMS (m/s) of each table axis within one-third octave of ``f_r`` (Hz), shape
    (n_axes,); ``points`` grid points across the band."""
    half = modetable.HALF_WIDTH_OCT
    f = np.linspace(f_r * 2.0 ** (-half) * 0.999, f_r * 2.0 ** half * 1.001, points)
    p = top.psd(f)
    return np.array([band_rms_around(f, p[:, j], f_r, half) for j in range(p.shape[1])])


def resonances(top: TopVelocity, axes: Sequence[str]) -> dict[str, float]:
    """The reference resonance (Hz) of each axis: :func:`.modetable.resonance_frequency` of the
    predicted ASD on a :data:`SEARCH_STEP_HZ` grid over :data:`.modetable.RESONANCE_RANGE_HZ`."""
    lo, hi = modetable.RESONANCE_RANGE_HZ
    f = np.arange(lo, hi + SEARCH_STEP_HZ / 2, SEARCH_STEP_HZ)
    p = top.psd(f)
    return {a: modetable.resonance_frequency(f, np.sqrt(p[:, j])) for j, a in enumerate(axes)}


def predict_table4(cfg: SystemConfig, modes: Sequence[Mode] = ALL_MODES,
                   reference: Mode = Mode.PASSIVE) -> Table4:
    """Table 4 from the model (module docstring).

    Parameters
    ----------
    cfg : SystemConfig
    modes : sequence of Mode
        Rows of the table (the reference is always computed).
    reference : Mode
        The mode every row is normalised to.
    """
    axes = table_axes(cfg)
    ref = TopVelocity(cfg, reference)
    out = Table4(reference.label, resonances(ref, axes))
    base = {a: band_rms(ref, out.resonance_hz[a])[j] for j, a in enumerate(axes)}
    for m in modes:
        top = ref if m is reference else TopVelocity(cfg, m)
        rms = {a: (float(band_rms(top, out.resonance_hz[a])[j]) if top.stable else math.inf)
               for j, a in enumerate(axes)}
        out.band_rms_mps[m.label] = rms
        out.values[m.label] = {a: modetable.normalize(rms[a], base[a])[0] for a in axes}
    return out


__all__ = ["Table4", "TopVelocity", "band_rms", "predict_table4", "resonances", "table_axes"]
