"""Parameter sweeps and frequency responses of the model (no CLI, no plotting).

:func:`sweep` scales one passive parameter by a list of factors: the eigenvalue loci (paper
Fig. 3) and the FRC and analytic PSD of the top stage (paper Fig. 6; unit ground-velocity white
noise and white force noise on every table, uncorrelated). :func:`transmissibility` is
``v_pi/v_b`` of every stage in a control mode, on the paper's continuous model or on the loop
as it runs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from dcsms_ros.core import analytics
from dcsms_ros.core.check import Pole, ideal_poles, oscillatory
from dcsms_ros.core.config import SystemConfig, scaled
from dcsms_ros.core.loop_model import Response, loop_model
from dcsms_ros.core.lti import Array, CArray, ss_response
from dcsms_ros.core.model import axis_names, input_slices, plant_state_space
from dcsms_ros.core.modes import Mode


def top_stage_response(cfg: SystemConfig, axis: str, f_hz: Array) -> tuple[CArray, CArray]:
    """``v_pN/v_b`` and ``v_pN/F_i`` (force on table i along ``axis``, i = 1..N) of the passive
    plant: shapes (len(f),) and (len(f), N)."""
    ss = plant_state_space(cfg)
    g_sl, _, w_sl = input_slices(cfg)
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    j = axis_names(dof).index(axis)
    out_row = (n - 1) * dof + j
    s = 2j * math.pi * np.asarray(f_hz, dtype=float)
    cols = [g_sl.start + j] + [w_sl.start + i * dof + j for i in range(n)]
    h = [ss_response(ss.a, ss.b[:, [col]], ss.c[[out_row], :], 0.0, s) for col in cols]
    return h[0], np.stack(h[1:], axis=1)


def eigenvalues_hz(cfg: SystemConfig) -> CArray:
    """Eigenvalues of the passive plant / 2 pi (Hz), by imaginary then real part."""
    lam = np.linalg.eigvals(plant_state_space(cfg).a) / (2.0 * math.pi)
    return np.asarray(sorted(lam, key=lambda z: (z.imag, z.real)), dtype=complex)


def track(loci: Sequence[CArray]) -> CArray:
    """Reorder each step's eigenvalues to continue the nearest track of the step before
    (assignment problem), so a line follows one root; shape (steps, n_roots)."""
    tracks = [np.asarray(loci[0])]
    for lam in loci[1:]:
        cost = np.abs(tracks[-1][:, None] - np.asarray(lam)[None, :])
        _, col = linear_sum_assignment(cost)
        tracks.append(np.asarray(lam)[col])
    return np.vstack(tracks)


def pick(n: int, k: int) -> list[int]:
    """At most ``k`` indices of ``range(n)``, evenly spread, first and last included."""
    if n <= k:
        return list(range(n))
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, k)})


@dataclass(frozen=True)
class Sweep:
    """One parameter scaled by each factor.

    Attributes
    ----------
    factors : list of float
        The factors, in the given order.
    loci : list of complex ndarray
        Passive eigenvalues / 2 pi (Hz) per factor (:func:`eigenvalues_hz`).
    modes : list of list of Pole
        Oscillatory modes of the paper's continuous model per factor, lowest first.
    picked : list of int
        Indices of the factors whose responses were computed (:func:`pick`).
    frc, psd : list of ndarray
        ``v_pN/v_b`` (complex) and the PSD of ``v_pN`` ((m/s)^2/Hz) per picked factor.
    """

    factors: list[float]
    loci: list[CArray]
    modes: list[list[Pole]]
    picked: list[int]
    frc: list[CArray]
    psd: list[Array]


def sweep(base: SystemConfig, param: str, factors: Sequence[float], axis: str, f_hz: Array,
          ground_psd: float = 1.0, force_psd: float = 1000.0, curves: int = 6) -> Sweep:
    """Scale ``param`` (m<i>, c<i>, k<i>; :func:`.config.scaled`) of ``base`` by each factor.

    ``ground_psd`` ((m/s)^2/Hz) and ``force_psd`` (N^2/Hz, on every table, uncorrelated) are
    one-sided white inputs; responses are computed for ``curves`` factors."""
    cfgs = [scaled(base, param, x) for x in factors]
    loci = [eigenvalues_hz(c) for c in cfgs]
    modes = [oscillatory(ideal_poles(c, Mode.PASSIVE)) for c in cfgs]
    picked = pick(len(cfgs), curves)
    frc: list[CArray] = []
    psd: list[Array] = []
    for i in picked:
        h_g, h_f = top_stage_response(cfgs[i], axis, f_hz)
        frc.append(h_g)
        psd.append(ground_psd * np.abs(h_g) ** 2 + force_psd * np.sum(np.abs(h_f) ** 2, axis=1))
    return Sweep(list(factors), loci, modes, picked, frc, psd)


def transmissibility(cfg: SystemConfig, mode: Mode, axis: str, f: Array,
                     ideal: bool = False) -> list[CArray]:
    """``v_pi/v_b`` (true stage velocity over ground velocity) of each stage along ``axis``:
    the loop as it runs (:mod:`.loop_model`), or ``ideal`` the paper's continuous model."""
    if ideal:
        return [analytics.freq_response(tf, f)
                for tf in analytics.transmissibility(cfg, mode, axis)]
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    a = axis_names(dof).index(axis)
    m = loop_model(cfg, mode)
    rows = [m.outputs["stage"].start + i * dof + a for i in range(n)]
    h = Response(m.select([m.inputs["ground"].start + a], rows))(f)
    return [h[:, i, 0] for i in range(n)]


__all__ = ["Sweep", "eigenvalues_hz", "pick", "sweep", "top_stage_response", "track",
           "transmissibility"]
