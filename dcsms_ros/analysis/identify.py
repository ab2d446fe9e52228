"""Identify physical parameters from measured frequency responses (``dcsms fit``).

Data: every usable bin (:mod:`.frf`: random error of |H1| at most 10 %) of the mobility of excited
segments and of the transmissibility of the segments, in 0.5-100 Hz. Model: the discrete loop
of each segment's mode (:class:`.modelfrf.LoopFrf`), the controllers and the decoupling as the
bag's configuration ran them, the plant (and its geophones) with the candidate parameters, seen
through the estimator's Welch window (:func:`.modelfrf.as_estimated`). Weighted least squares
(``scipy.optimize.least_squares``) of ``ln(H_model / H_measured)`` (real part: the level error,
imaginary part: the phase error) divided by each bin's random error ``eps``
(:func:`.estimators.h1_random_error`, a function of the coherence and the number of averages),
so every residual is ~N(0, 1) where the model is right; the parameters are fitted as
logarithms (positive, scale-free).

Standard deviations: ``sqrt(diag((J^T J)^-1))`` at the solution, times
``sqrt(max(1, chi2_reduced))`` (a model that does not fit inflates them) and
``sqrt(ENBW)`` = sqrt(1.5) (neighbouring Hann bins are correlated, so the bins are fewer
independent measurements than they look).

Parameters (``--params``, :func:`parse_params`):

* 1-DOF: ``m<i>`` (kg), ``k<i>`` (N/m), ``c<i>`` (N*s/m) of stage i;
* 6-DOF: ``m<i>`` and ``k<i><a>``, ``c<i><a>`` for a = x, y, z: the suspension under stage i
  along that axis, summed over its mounts (each mount's value scaled alike);
* the geophones (every channel alike): ``fg`` natural frequency (Hz), ``zg`` damping ratio
  (-), ``sg`` sensitivity (V/(m/s)): the true values behind the readings, which the rig
  converted with the configured ones.

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import frf as frfmod
from dcsms_ros.analysis import plots
from dcsms_ros.analysis.modelfrf import LoopFrf, as_estimated
from dcsms_ros.analysis.reader import BagData, Progress, config_from_yaml, read_bag
from dcsms_ros.analysis.segments import (
    MIN_SEGMENT_S,
    SETTLE_S,
    align,
    split_excited,
    split_segments,
)
from dcsms_ros.core.config import SystemConfig, config_from_flat, params_text
from dcsms_ros.core.modes import Mode
from dcsms_ros.errors import DcsmsError
from dcsms_ros.jsonutil import jsonable

#: Equivalent noise bandwidth of the Hann window in bins (the std inflation, squared).
HANN_ENBW = 1.5
#: Smallest random error a bin is weighted with (a model error of 0.1 % is not noise).
MIN_EPS = 1e-3
#: Singular values below this fraction of the largest: the data cannot separate parameters.
RANK_TOL = 1e-7

_SENSOR = {"fg": ("sensors.natural_frequency_hz", "Hz"), "zg": ("sensors.damping_ratio", "-"),
           "sg": ("sensors.sensitivity_v_per_mps", "V/(m/s)")}
_PHYS = {"m": ("mass", "kg"), "k": ("stiffness", "N/m"), "c": ("damping", "N*s/m")}


@dataclass(frozen=True)
class Param:
    """One fitted parameter: ``name`` (``m1``, ``k2``, ``c1x``, ``fg`` ...), ``unit``, ``kind``
    (``m``, ``k``, ``c`` or the sensor name), ``stage`` (1-based, 0 for the geophones) and
    ``axis`` (6-DOF suspensions; "" otherwise)."""

    name: str
    unit: str
    kind: str
    stage: int = 0
    axis: str = ""

    def value(self, cfg: SystemConfig) -> float:
        """The parameter's value in ``cfg`` (its unit)."""
        flat = cfg.params or {}
        if self.kind in _SENSOR:
            return float(flat[_SENSOR[self.kind][0]])
        key = f"stage{self.stage}."
        if self.axis:
            j = "xyz".index(self.axis)
            what = "stiffness" if self.kind == "k" else "damping"
            return float(sum(flat[key + f"mounts.{what}"][j::3]))
        return float(flat[key + _PHYS[self.kind][0]])

    def write(self, flat: dict[str, Any], cfg: SystemConfig, value: float) -> None:
        """Put ``value`` into the flat parameters ``flat`` (of ``cfg``'s layout)."""
        if self.kind in _SENSOR:
            flat[_SENSOR[self.kind][0]] = value
            return
        key = f"stage{self.stage}."
        if not self.axis:
            flat[key + _PHYS[self.kind][0]] = value
            return
        j = "xyz".index(self.axis)
        name = key + f"mounts.{'stiffness' if self.kind == 'k' else 'damping'}"
        old = list(flat[name])
        scale = value / self.value(cfg)
        flat[name] = [v * scale if i % 3 == j else v for i, v in enumerate(old)]


def parse_params(cfg: SystemConfig, text: str | None) -> list[Param]:
    """``m1,k1,c1,...`` (or the defaults: every mass, stiffness and damping in 1-DOF; every
    suspension's stiffness and damping along x, y and z in 6-DOF).

    Raises
    ------
    DcsmsError
        An unknown name, a stage that does not exist, a name given twice, or a per-axis name
        in 1-DOF (or a plain ``k1``/``c1`` in 6-DOF).
    """
    n, six = cfg.plant.num_stages, cfg.plant.dof == 6
    if text is None:
        names = ([f"{k}{i}{a}" for i in range(1, n + 1) for k in "kc" for a in "xyz"] if six
                 else [f"{k}{i}" for i in range(1, n + 1) for k in "mkc"])
    else:
        names = [t.strip() for t in text.split(",") if t.strip()]
    out: list[Param] = [_param(name, n, six) for name in names]
    dup = {p.name for p in out if sum(q.name == p.name for q in out) > 1}
    if dup:
        raise DcsmsError(f"--params: {', '.join(sorted(dup))} given twice")
    if not out:
        raise DcsmsError("--params: no parameter named")
    return out


def _param(name: str, n: int, six: bool) -> Param:
    if name in _SENSOR:
        return Param(name, _SENSOR[name][1], name)
    kind, rest = name[:1], name[1:]
    axis = ""
    if rest and rest[-1] in "xyz":
        rest, axis = rest[:-1], rest[-1]
    hint = ("m<i>, k<i>, c<i> (1dof), m<i>, k<i><x|y|z>, c<i><x|y|z> (6dof), fg, zg, sg")
    if kind not in _PHYS or not rest.isdigit():
        raise DcsmsError(f"--params: unknown parameter {name!r}; expected {hint}")
    stage = int(rest)
    if not 1 <= stage <= n:
        raise DcsmsError(f"--params {name}: stage{stage} does not exist ({n} stages)")
    if kind == "m" and axis:
        raise DcsmsError(f"--params {name}: a mass has no axis; use m{stage}")
    if kind in "kc" and six != bool(axis):
        raise DcsmsError(f"--params {name}: " + (
            f"a 6dof suspension is fitted per axis: {kind}{stage}x, {kind}{stage}y, "
            f"{kind}{stage}z" if six else f"a 1dof plant has no axes: use {kind}{stage}"))
    return Param(name, _PHYS[kind][1], kind, stage, axis)


@dataclass
class Measured:
    """One measured response of one stage, restricted to its usable bins.

    Attributes
    ----------
    kind : str
        ``mobility`` ((m/s)/N) or ``transmissibility`` (-).
    mode : Mode
    axis : str
    stage : int
        Output stage (1-based).
    excited : int
        Excited stage for a mobility (0 otherwise).
    f, h, eps, sxx : ndarray, shape (F,)
        Bin frequencies (Hz), H1, random error of |H1|, input auto-spectrum.
    fs : float
    nperseg : int
    label : str
        Segment (bag, mode, excitation) for reports.
    all_f, all_h : ndarray
        Every bin of the compare range (for the plots).
    """

    kind: str
    mode: Mode
    axis: str
    stage: int
    excited: int
    f: np.ndarray
    h: np.ndarray
    eps: np.ndarray
    sxx: np.ndarray
    fs: float
    nperseg: int
    label: str
    all_f: np.ndarray = field(default_factory=lambda: np.zeros(0))
    all_h: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))

    @property
    def name(self) -> str:
        src = f"F{self.excited}" if self.kind == "mobility" else "v_b"
        return f"v_p{self.stage}/{src} {self.axis}"


@dataclass
class Collected:
    """What :func:`collect` found: the responses, the configuration they ran with, and notes."""

    measured: list[Measured]
    cfg: SystemConfig
    truth: bool
    warnings: list[str] = field(default_factory=list)
    segments: list[dict[str, Any]] = field(default_factory=list)


def collect(bags: Sequence[str | Path], config: SystemConfig | None = None,
            kinds: Sequence[str] = frfmod.KINDS, settle_s: float = SETTLE_S,
            progress: Progress | None = None) -> Collected:
    """Measured responses of every segment of ``bags`` (module docstring).

    Parameters
    ----------
    bags : sequence of path
    config : SystemConfig, optional
        The configuration the rig ran with, instead of the one recorded on ``/dcsms/config``.
    kinds : sequence of str
        Which responses to use (``mobility``, ``transmissibility``).

    Raises
    ------
    DcsmsError
        No configuration, bags recorded with different configurations, or not one usable bin.
    """
    out: list[Measured] = []
    warnings: list[str] = []
    segs_js: list[dict[str, Any]] = []
    cfg_used: SystemConfig | None = config
    truth = False
    texts: set[str] = set()
    for b in bags:
        data = read_bag(b, progress)
        truth = truth or data.source == "truth"
        if config is None:
            if not data.config_text:
                raise DcsmsError(f"{data.path}: no /dcsms/config: give the configuration the rig "
                                 "ran with (--config)")
            texts.add(data.config_text)
            if len(texts) > 1:
                raise DcsmsError(f"{data.path}: recorded with another configuration than the "
                                 "bags before it; fit bags of one configuration (or --config)")
            cfg_used = config_from_yaml(data.config_text, f"{data.path}:/dcsms/config")
        assert cfg_used is not None
        out += _bag_responses(data, cfg_used, kinds, settle_s, warnings, segs_js)
    if cfg_used is None:
        raise DcsmsError("no bags")
    if not out:
        raise DcsmsError("no usable bins in the bags (no segment with a known mode and a "
                         "response whose random error is <= 10 %)")
    return Collected(out, cfg_used, truth, warnings, segs_js)


def _bag_responses(data: BagData, cfg: SystemConfig, kinds: Sequence[str], settle_s: float,
                   warnings: list[str], segs_js: list[dict[str, Any]]) -> list[Measured]:
    out: list[Measured] = []
    ref = next(iter(data.bodies.values()))
    if ref.stamp_ns.size == 0:
        return out
    axes = ["z"] if cfg.plant.dof == 1 else ["x", "y", "z"]
    segs = split_segments(data.modes, int(ref.stamp_ns[0]), int(ref.stamp_ns[-1]), settle_s)
    for seg in split_excited(segs, data.excitation, settle_s):
        where = f"{data.path} [{seg.label} @ {seg.t0_ns * 1e-9:.2f} s]"
        if seg.mode is None or seg.duration_s < MIN_SEGMENT_S:
            warnings.append(f"{where}: no known mode or shorter than {MIN_SEGMENT_S:g} s; "
                            "not used")
            continue
        al = align(data, seg)
        if al.stamp_ns.size < 64 or al.fs <= 0:
            continue
        nper = est.choose_nperseg(al.fs, al.stamp_ns.size)
        stages = sorted((s for s in al.bodies if s != "ground"), key=lambda s: int(s[5:]))
        outputs = {s: al.bodies[s] for s in stages}
        frame = data.excitation.frame_id if data.excitation is not None else ""
        exc_stage = int(frame[5:]) if seg.excited and frame[5:].isdigit() else 0
        label = f"{data.path.name}: {seg.label}" + (f" + excitation {frame}" if seg.excited
                                                    else "")
        used = {}
        for a in axes:
            j = "xyz".index(a)
            ests = []
            if "transmissibility" in kinds and "ground" in al.bodies:
                ests.append(frfmod.estimate("transmissibility", al.bodies["ground"][:, j],
                                            outputs, a, al.fs, nper, "", ""))
            if ("mobility" in kinds and al.excitation is not None
                    and a in frfmod.excited_axes(al.excitation, [a])):
                ests.append(frfmod.estimate("mobility", al.excitation[:, j], outputs, a,
                                            al.fs, nper, "", ""))
            for e in ests:
                for i, s in enumerate(e.stages):
                    ok = e.usable(i)
                    t = e.tfs[i]
                    used[f"{e.kind} {s} {a}"] = int(ok.sum())
                    if not ok.any():
                        continue
                    band = ((t.f >= frfmod.COMPARE_RANGE_HZ[0])
                            & (t.f <= frfmod.COMPARE_RANGE_HZ[1]))
                    eps = est.h1_random_error(t.coherence, t.averages)
                    assert e.sxx is not None
                    out.append(Measured(
                        e.kind, seg.mode, a, int(s[5:]),
                        exc_stage if e.kind == "mobility" else 0, t.f[ok], t.h[ok],
                        np.maximum(eps[ok], MIN_EPS), e.sxx[ok], al.fs, nper, label,
                        t.f[band], t.h[band]))
        segs_js.append({"segment": label, "t_start_s": seg.t0_ns * 1e-9,
                        "duration_s": seg.duration_s, "usable_bins": used})
    return out


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
    phys = {(p.kind, p.stage, p.axis) for p in params if p.kind in _PHYS}
    axes = [""] if cfg.plant.dof == 1 else ["x", "y", "z"]
    every = {("m", i, "") for i in range(1, cfg.plant.num_stages + 1)}
    every |= {(k, i, a) for i in range(1, cfg.plant.num_stages + 1) for k in "kc" for a in axes}
    all_phys = every <= phys
    sensors = sorted(kinds & set(_SENSOR))
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


__all__ = ["Collected", "FitResult", "Measured", "Param", "check_identifiable", "collect",
           "fit", "parse_params", "write"]
