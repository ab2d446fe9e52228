"""Fit physical parameters to measured frequency responses (``dcsms fit``).

Data: :func:`.identify.collect`. Model: the discrete loop of each segment's mode
(:class:`.modelfrf.LoopFrf`), the controllers and the decoupling as the bag's configuration ran
them, the plant (and its geophones) with the candidate parameters, seen through the estimator's
Welch window (:func:`.modelfrf.as_estimated`). Weighted least squares
(``scipy.optimize.least_squares``) of ``ln(H_model / H_measured)`` (real part: the level error,
imaginary part: the phase error) divided by each bin's random error ``eps``
(:func:`.estimators.h1_random_error`, a function of the coherence and the number of averages), so
every residual is ~N(0, 1) where the model is right; the parameters are fitted as logarithms
(positive, scale-free).

Standard deviations: ``sqrt(diag((J^T J)^-1))`` at the solution, times
``sqrt(max(1, chi2_reduced))`` (a model that does not fit inflates them) and
``sqrt(ENBW)`` = sqrt(1.5) (neighbouring Hann bins are correlated, so the bins are fewer
independent measurements than they look).

What the data can identify (otherwise :class:`~dcsms_ros.errors.DcsmsError`, one line):

* transmissibility is unchanged when every mass, stiffness and damping is scaled alike: without
  a force excitation they cannot all be fitted (absolute masses need a known force);
* the geophones (same model on every channel) cancel in a transmissibility: ``fg``, ``zg``,
  ``sg`` need a mobility; their effect is in the decoupled velocities as well as in the raw
  channels (the decoupling's extension is known from the configuration), so the velocity topics
  suffice, but not true velocities (``/dcsms/truth/*``: no sensor);
* ``sg`` scales every reading like ``1 / (all of m, k, c)``: not together with all of them; and
  in closed loop the readings also scale the feedback, which this fit does not model: Passive
  segments only;
* any other parameter the usable bins do not constrain (the Jacobian at the start is rank
  deficient, e.g. an axis without data) is named.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from dcsms_ros.analysis import plots
from dcsms_ros.analysis.identify import PHYSICAL_PARAMS, SENSOR_PARAMS, Collected, Measured, Param
from dcsms_ros.analysis.modelfrf import LoopFrf, as_estimated
from dcsms_ros.core.config import SystemConfig, config_from_flat, params_text
from dcsms_ros.core.modes import Mode
from dcsms_ros.errors import DcsmsError
from dcsms_ros.jsonutil import jsonable

#: Equivalent noise bandwidth of the Hann window in bins (the std inflation, squared).
HANN_ENBW = 1.5
#: Singular values below this fraction of the largest: the data cannot separate parameters.
RANK_TOL = 1e-7


@dataclass
class FitResult:
    """Result of :func:`fit`.

    Attributes
    ----------
    params : list of Param
    start, value, std : ndarray, shape (P,)
        Start values, fitted values and their standard deviations (each parameter's unit).
    residual_db, residual_db_start : float
        RMS of ``20 log10 |H_model / H_measured|`` over the fitted bins, at the solution and at
        the start (dB).
    chi2_reduced : float
        Sum of squared weighted residuals per degree of freedom (~1: the model explains the
        data to within its random error).
    bins : int
        Fitted bins (each gives two residuals: level and phase).
    cfg : SystemConfig
        The configuration the rig ran with; ``fitted`` the same with the fitted values.
    models_start, models_fit : list of ndarray
        Model on each measured response's ``all_f`` at the start and at the solution.
    """

    params: list[Param]
    start: np.ndarray
    value: np.ndarray
    std: np.ndarray
    residual_db: float
    residual_db_start: float
    chi2_reduced: float
    bins: int
    cfg: SystemConfig
    fitted: SystemConfig
    measured: list[Measured]
    models_start: list[np.ndarray]
    models_fit: list[np.ndarray]
    evaluations: int = 0
    correlation: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``{"parameters": {name: {"value", "std", "start", "unit"}}, ...}``."""
        return {
            "parameters": {p.name: {"value": float(v), "std": float(s), "start": float(s0),
                                    "unit": p.unit}
                           for p, v, s, s0 in zip(self.params, self.value, self.std,
                                                  self.start, strict=True)},
            "residual_db": self.residual_db, "residual_db_start": self.residual_db_start,
            "chi2_reduced": self.chi2_reduced, "bins": self.bins,
            "responses": [{"segment": m.label, "response": m.name, "bins": int(m.f.size)}
                          for m in self.measured],
            "evaluations": self.evaluations,
        }


def _plant(cfg: SystemConfig, params: Sequence[Param], values: np.ndarray) -> SystemConfig:
    flat = dict(cfg.params or {})
    for p, v in zip(params, values, strict=True):
        if p.kind != "sg":  # the sensitivity only scales the readings (LoopFrf gain)
            p.write(flat, cfg, float(v))
    return config_from_flat(flat, cfg.source)


def check_identifiable(col: Collected, params: Sequence[Param]) -> None:
    """The rules of the module docstring that need no model.

    Raises
    ------
    DcsmsError
    """
    cfg = col.cfg
    kinds = {p.kind for p in params}
    has_mobility = any(m.kind == "mobility" for m in col.measured)
    phys = {(p.kind, p.stage, p.axis) for p in params if p.kind in PHYSICAL_PARAMS}
    axes = [""] if cfg.plant.dof == 1 else ["x", "y", "z"]
    every = {("m", i, "") for i in range(1, cfg.plant.num_stages + 1)}
    every |= {(k, i, a) for i in range(1, cfg.plant.num_stages + 1) for k in "kc" for a in axes}
    all_phys = every <= phys
    sensors = sorted(kinds & set(SENSOR_PARAMS))
    if all_phys and not has_mobility:
        masses = ", ".join(p.name for p in params if p.kind == "m")
        raise DcsmsError(
            f"cannot identify {masses}: without a force excitation (no excited segment with "
            "usable bins) the ground transmissibility is unchanged when every mass, stiffness "
            "and damping is scaled alike, so absolute masses are not fixed; record with an "
            "excitation (dcsms sim --excite, the excitation node) or leave a known parameter "
            "out of --params")
    if sensors and not has_mobility:
        raise DcsmsError(
            f"cannot identify {', '.join(sensors)}: the geophones are alike on every channel "
            "and cancel in a transmissibility; they need a force excitation (mobility)")
    if sensors and col.truth:
        raise DcsmsError(f"cannot identify {', '.join(sensors)}: the bags hold true "
                         "velocities only (/dcsms/truth/*), which no sensor measured")
    if "sg" in kinds and all_phys:
        raise DcsmsError(
            "cannot identify sg together with every mass, stiffness and damping: scaling all "
            "of them by a and the sensitivity by 1/a gives the same readings; leave a known "
            "parameter out of --params")
    if "sg" in kinds:
        active = sorted({m.mode.label for m in col.measured if m.mode is not Mode.PASSIVE})
        if active:
            raise DcsmsError(
                f"cannot identify sg from {', '.join(active)} segments: in closed loop the "
                "sensitivity also scales the feedback, which this fit does not model; fit sg "
                "from Passive recordings only")


class _Problem:
    """Residuals of the weighted least squares in log-parameters ``x = ln(p / p0)``."""

    def __init__(self, col: Collected, params: Sequence[Param],
                 start: dict[str, float] | None = None) -> None:
        self.col, self.params = col, list(params)
        start = start or {}
        self.p0 = np.array([start.get(p.name, p.value(col.cfg)) for p in params])
        if np.any(self.p0 <= 0):
            bad = [p.name for p, v in zip(params, self.p0, strict=True) if v <= 0]
            raise DcsmsError(f"cannot fit {', '.join(bad)}: the start value is 0 (the fit works "
                             "on logarithms); start from a configuration where it is > 0 "
                             "(--config / --set)")
        self.sg = next((i for i, p in enumerate(params) if p.kind == "sg"), None)
        #: the sensitivity the rig converted with: readings = true / rig * velocity
        self.sg_rig = col.cfg.sensors.sensitivity_v_per_mps
        self.evaluations = 0

    def models(self, x: np.ndarray, on_all: bool = False) -> list[np.ndarray]:
        """Model of every measured response at ``exp(x) * p0``, on its fitted bins (or on all
        its compare-range bins)."""
        values = self.p0 * np.exp(x)
        plant = _plant(self.col.cfg, self.params, values)
        gain = 1.0 if self.sg is None else float(values[self.sg] / self.sg_rig)
        frfs: dict[Mode, LoopFrf] = {}
        out = []
        self.evaluations += 1
        for m in self.col.measured:
            if m.mode not in frfs:
                frfs[m.mode] = LoopFrf(self.col.cfg, m.mode, plant=plant, truth=self.col.truth,
                                       gain=gain)
            lf = frfs[m.mode]
            resp: Callable[[np.ndarray], np.ndarray]
            if m.kind == "mobility":
                def resp(f: np.ndarray, lf: LoopFrf = lf, m: Measured = m) -> np.ndarray:
                    return lf.mobility(f, m.excited, m.axis, [m.stage])[:, 0]
            else:
                def resp(f: np.ndarray, lf: LoopFrf = lf, m: Measured = m) -> np.ndarray:
                    return lf.transmissibility(f, m.axis, [m.stage])[:, 0]
            f = m.all_f if on_all else m.f
            sxx = None if on_all else m.sxx
            out.append(as_estimated(resp, f, m.fs, m.nperseg, sxx))
        return out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        parts = []
        for m, h in zip(self.col.measured, self.models(x), strict=True):
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.log(h / m.h) / m.eps
            r = np.where(np.isfinite(r), r, 1e6)
            parts += [r.real, r.imag]
        return np.concatenate(parts)

    def level_db(self, x: np.ndarray) -> float:
        errs = [20 * np.log10(np.abs(h / m.h))
                for m, h in zip(self.col.measured, self.models(x), strict=True)]
        e = np.concatenate(errs)
        return float(np.sqrt(np.mean(e ** 2)))


def fit(col: Collected, params: Sequence[Param], start: dict[str, float] | None = None,
        max_evaluations: int = 400) -> FitResult:
    """Fit ``params`` to the responses of ``col`` (module docstring).

    Parameters
    ----------
    col : Collected
    params : sequence of Param
    start : dict of name to float, optional
        Start values (each parameter's unit) instead of the configuration's.
    max_evaluations : int
        Model evaluations the least-squares solver may spend.

    Raises
    ------
    DcsmsError
        A parameter the data cannot identify (:func:`check_identifiable`, or a rank-deficient
        Jacobian at the start, naming the parameters involved).
    """
    check_identifiable(col, params)
    unknown = sorted(set(start or {}) - {p.name for p in params})
    if unknown:
        raise DcsmsError(f"--start {', '.join(unknown)}: not among the fitted parameters")
    prob = _Problem(col, params, start)
    x0 = np.zeros(len(params))
    jac0 = _jacobian(prob, x0)
    _check_rank(jac0, params)
    sol = least_squares(prob.residuals, x0, method="trf", x_scale="jac", diff_step=1e-4,
                        max_nfev=max_evaluations)
    jac = sol.jac
    dof = max(sol.fun.size - len(params), 1)
    chi2 = float(np.sum(sol.fun ** 2) / dof)
    cov = _pinv_cov(jac) * max(1.0, chi2) * HANN_ENBW
    sd_log = np.sqrt(np.maximum(np.diag(cov), 0.0))
    value = prob.p0 * np.exp(sol.x)
    corr = cov / np.outer(sd_log, sd_log) if np.all(sd_log > 0) else None
    flat = dict(col.cfg.params or {})
    for p, v in zip(params, value, strict=True):
        p.write(flat, col.cfg, float(v))
    fitted = config_from_flat(flat, col.cfg.source)
    return FitResult(
        list(params), prob.p0, value, value * sd_log, prob.level_db(sol.x),
        prob.level_db(x0), chi2, sum(m.f.size for m in col.measured), col.cfg, fitted,
        col.measured, prob.models(x0, on_all=True), prob.models(sol.x, on_all=True),
        prob.evaluations, corr)


def _jacobian(prob: _Problem, x: np.ndarray, step: float = 1e-4) -> np.ndarray:
    """Central differences of the residuals, shape (R, P)."""
    cols = []
    for j in range(x.size):
        d = np.zeros_like(x)
        d[j] = step
        cols.append((prob.residuals(x + d) - prob.residuals(x - d)) / (2 * step))
    return np.column_stack(cols)


def _pinv_cov(jac: np.ndarray) -> np.ndarray:
    return np.asarray(np.linalg.pinv(jac.T @ jac), dtype=np.float64)


def _check_rank(jac: np.ndarray, params: Sequence[Param]) -> None:
    """Refuse parameters the data do not constrain: a Jacobian column that is ~zero, or a
    combination of columns that is (the parameters with the largest share of the null
    direction are named)."""
    norms = np.linalg.norm(jac, axis=0)
    top = float(np.max(norms)) if norms.size else 0.0
    dead = [p.name for p, n in zip(params, norms, strict=True) if not n > RANK_TOL * top]
    if dead:
        raise DcsmsError(f"cannot identify {', '.join(dead)}: no usable bin of the bags "
                         "depends on it (no excitation or ground response on that axis or "
                         "stage)")
    scaled = jac / norms
    _, s, vt = np.linalg.svd(scaled, full_matrices=False)
    if s[-1] < math.sqrt(RANK_TOL) * s[0]:
        v = np.abs(vt[-1])
        names = [p.name for p, w in zip(params, v, strict=True) if w >= 0.25 * v.max()]
        raise DcsmsError(f"cannot identify {', '.join(names)} separately: the usable bins "
                         "depend only on a combination of them (fix one of them, or add an "
                         "excitation on another stage)")


def write(result: FitResult, out: Path, bags: Sequence[str | Path]) -> list[Path]:
    """Write ``fit.yaml`` (the rig's configuration with the fitted values: a params file for
    ``--config``), ``fit.json`` and one ``fit_<response>_<axis>.png`` per kind and axis
    (measured against the model at the start and fitted) into ``out`` (created).

    Raises
    ------
    DcsmsError
        ``out`` cannot be created.
    """
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DcsmsError(f"{out}: cannot create output directory: {exc.strerror}") from None
    head = [f"# dcsms fit of {', '.join(str(b) for b in bags)}",
            "# fitted (std): " + ", ".join(f"{p.name} = {v:.6g} ({s:.2g}) {p.unit}"
                                           for p, v, s in zip(result.params, result.value,
                                                              result.std, strict=True)),
            (f"# residual {result.residual_db:.2f} dB RMS (start "
             f"{result.residual_db_start:.2f} dB), chi2/dof {result.chi2_reduced:.2f}, "
             f"{result.bins} bins"), ""]
    files = [out / "fit.yaml", out / "fit.json"]
    files[0].write_text("\n".join(head) + params_text(result.fitted.params or {}))
    files[1].write_text(json.dumps(jsonable(result.to_dict()), indent=1, allow_nan=False)
                        + "\n")
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for m, h0, h1 in zip(result.measured, result.models_start, result.models_fit, strict=True):
        groups.setdefault((m.kind, m.axis), []).append({
            "label": f"{m.label}: {m.name}", "f": m.all_f, "h": m.all_h,
            "used": np.isin(m.all_f, m.f), "h_start": h0, "h_fit": h1})
    for (kind, axis), curves in groups.items():
        ylabel = "|v_p/F| ((m/s)/N)" if kind == "mobility" else "|v_p/v_b|"
        files.append(plots.plot_fit(
            out / f"fit_{kind}_{axis}.png", curves, ylabel,
            f"dcsms fit: {kind}, axis {axis} (faint: not fitted; dotted: start; dashed: "
            f"fitted, {result.residual_db:.2f} dB RMS)"))
    return files


__all__ = ["FitResult", "check_identifiable", "fit", "write"]
