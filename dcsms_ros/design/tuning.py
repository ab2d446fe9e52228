"""Controller gains chosen on the loop as it runs: constrained, derivative-free optimisation.

The knobs (:class:`Knob`) are velocity-feedback gains per stage and axis, the feedforward gain
and, optionally, the high-pass and sensor-extension corners. Each candidate is judged on the
discrete model of the loop as it runs (:mod:`dcsms_ros.core.loop_model`):

* constraints (each a slack, feasible when >= 0): every mode stable, every loop-at-a-time and
  disk margin at least the minimum, every delay margin at least :data:`DELAY_BUFFER` times
  ``control.input_timeout_s`` (a real-time force is applied up to that late), every actuator's
  predicted force RMS at most limit / 4.
  Feedforward is no loop, so the poles and margins of a mode with and without FFC are the same:
  only the distinct sets of feedback loops are analysed;
* objective ``attenuation``: the largest over the table's axes of ln(Table-4 value of
  DFBC+FFC), the predicted top-stage band RMS at the Passive resonance relative to Passive
  (:mod:`dcsms_ros.analysis.predict`), taken smoothly (log-sum-exp, :data:`SOFTMAX`) so that
  every axis is pushed down, the worst first;
* objective ``table4``: the sum of squared ln(predicted / target) over the target's entries;
* optionally, the paper's ordering on some axes: FBC > FBC+FFC > DFBC > DFBC+FFC, each at
  least :data:`ORDER_GAP` times the next (so that the order survives a simulation's scatter).

The search is scipy's COBYQA in a box of normalised coordinates (log for gains and corners).
An infeasible start is fine: COBYQA works towards feasibility first.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from dcsms_ros.analysis.predict import TopVelocity, band_rms, resonances, table_axes
from dcsms_ros.core.check import actuator_limits
from dcsms_ros.core.config import SystemConfig, with_overrides
from dcsms_ros.core.loop_model import loop_model, poles
from dcsms_ros.core.margins import (
    OpenLoops,
    delay_margins,
    frequency_grid,
    margins,
    smallest_delay,
)
from dcsms_ros.core.model import axis_names
from dcsms_ros.core.modes import ALL_MODES, ControllerId, Mode, enabled_controllers
from dcsms_ros.core.safety import MIN_GM_DB, MIN_PM_DEG, PEAK_FACTOR
from dcsms_ros.core.spectra import rms, shaped
from dcsms_ros.errors import DcsmsError

Array = NDArray[np.float64]

#: Frequency points of the margin search while tuning (the final check uses the full grid).
TUNE_GRID_POINTS = 500
#: Margin kept above the minimum while tuning (dB, deg): the final check's finer grid can read a
#: margin a little lower than the tuning grid did.
MARGIN_BUFFER = (0.3, 1.0)
#: Least ratio of every delay margin to ``control.input_timeout_s`` while tuning.
DELAY_BUFFER = 1.05
#: Objectives :func:`tune` knows.
OBJECTIVES = ("attenuation", "table4")
#: Band-integration points while tuning.
TUNE_BAND_POINTS = 201
#: Sharpness of the smooth maximum over axes of the attenuation objective.
SOFTMAX = 4.0
#: The paper's Table-4 order, and the least ratio between neighbours when it is required.
ORDER = ("FBC", "FBC+FFC", "DFBC", "DFBC+FFC")
ORDER_GAP = 1.15


@dataclass(frozen=True)
class Knob:
    """One tuned value: ``name`` (dotted parameter), ``index`` into a list parameter (-1: a
    scalar), bounds ``lo``..``hi`` in the parameter's unit, searched in log space if ``log``."""

    name: str
    index: int
    lo: float
    hi: float
    log: bool = True

    @property
    def label(self) -> str:
        if self.index < 0:
            return self.name
        return f"{self.name}[{axis_names(6)[self.index]}]"

    def to_unit(self, value: float) -> float:
        """Parameter value -> [0, 1]."""
        v = min(max(value, self.lo), self.hi)
        if self.log:
            return math.log(v / self.lo) / math.log(self.hi / self.lo)
        return (v - self.lo) / (self.hi - self.lo)

    def from_unit(self, u: float) -> float:
        """[0, 1] -> parameter value."""
        u = min(max(u, 0.0), 1.0)
        if self.log:
            return self.lo * (self.hi / self.lo) ** u
        return self.lo + u * (self.hi - self.lo)


def default_knobs(cfg: SystemConfig, corners: bool = False,
                  rotations: bool = False, corner_min_hz: float = 0.02) -> list[Knob]:
    """Translational feedback gains of every stage (z in 1dof), the feedforward gain, and with
    ``rotations`` the rotational gains (6dof), with ``corners`` the feedback high-pass corners
    and the sensor extension corner.

    Gains: 10 .. 1e6 N*s/m (translations), 1 .. 1e5 N*m*s/rad (rotations); feedforward
    0 .. 1.05 (linear); corners ``corner_min_hz`` .. 1.0 Hz (how low the sensors can be trusted).
    """
    axes = [2] if cfg.plant.dof == 1 else [0, 1, 2] + ([3, 4, 5] if rotations else [])
    out = []
    for i in range(1, cfg.plant.num_stages + 1):
        for a in axes:
            lo, hi = (10.0, 1e6) if a < 3 else (1.0, 1e5)
            out.append(Knob(f"feedback.stage{i}.gain", a, lo, hi))
    out.append(Knob("feedforward.gain", -1, 0.0, 1.05, log=False))
    if corners:
        out += [Knob(f"feedback.stage{i}.highpass_hz", -1, corner_min_hz, 1.0)
                for i in range(1, cfg.plant.num_stages + 1)]
        out.append(Knob("sensors.extension_hz", -1, corner_min_hz, 1.0))
    return out


def _get(cfg: SystemConfig, k: Knob) -> float:
    assert cfg.params is not None
    v = cfg.params[k.name]
    return float(v[k.index] if k.index >= 0 else v)


def apply(cfg: SystemConfig, knobs: Sequence[Knob], values: Sequence[float]) -> SystemConfig:
    """``cfg`` with each knob set to its value (validated)."""
    assert cfg.params is not None
    over: dict[str, Any] = {}
    for k, v in zip(knobs, values, strict=True):
        if k.index >= 0:
            cur = list(over.get(k.name, cfg.params[k.name]))
            cur[k.index] = float(v)
            over[k.name] = cur
        else:
            over[k.name] = float(v)
    return with_overrides(cfg, over)


@dataclass
class Evaluation:
    """One candidate: ``objective``, ``slacks`` (constraint name -> slack, feasible >= 0),
    ``worst_gm_db``/``worst_pm_deg`` over every loop and disk, predicted Table-4 values."""

    objective: float
    slacks: dict[str, float]
    worst_gm_db: float
    worst_pm_deg: float
    table: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def feasible(self) -> bool:
        return all(v >= 0.0 for v in self.slacks.values())


def _loop_sets(cfg: SystemConfig) -> dict[frozenset[str], Mode]:
    """One mode per distinct set of feedback controllers (feedforward closes no loop)."""
    out: dict[frozenset[str], Mode] = {}
    for m in ALL_MODES:
        fb = frozenset(c for c in enabled_controllers(m, cfg.plant.num_stages)
                       if ControllerId.parse(c).feedback)
        if fb and fb not in out:
            out[fb] = m
    return out


class Problem:
    """Objective and constraints of one tuning run.

    Parameters
    ----------
    cfg : SystemConfig
        The starting configuration (everything not tuned stays as it is).
    knobs : sequence of Knob
    objective : str
        ``attenuation`` or ``table4``.
    target : mapping mode label -> axis -> factor, optional
        Required for ``table4``.
    min_gm_db, min_pm_deg : float
        Minimum margins (dB, deg).
    order : sequence of str
        Axes on which the paper's mode order must hold (:data:`ORDER`).
    order_gap : float
        Least ratio between neighbours in that order (default :data:`ORDER_GAP`).
    """

    def __init__(self, cfg: SystemConfig, knobs: Sequence[Knob], objective: str,
                 target: Mapping[str, Mapping[str, float]] | None = None,
                 min_gm_db: float = MIN_GM_DB, min_pm_deg: float = MIN_PM_DEG,
                 order: Sequence[str] = (), order_gap: float = ORDER_GAP) -> None:
        if objective not in OBJECTIVES:
            raise DcsmsError(f"objective {objective!r}: expected one of {', '.join(OBJECTIVES)}")
        if objective == "table4" and not target:
            raise DcsmsError("objective table4 needs a target (--target FILE)")
        self.cfg, self.knobs, self.objective = cfg, list(knobs), objective
        self.target = {m: dict(v) for m, v in (target or {}).items()}
        self.min_gm, self.min_pm = min_gm_db + MARGIN_BUFFER[0], min_pm_deg + MARGIN_BUFFER[1]
        self.axes = table_axes(cfg)
        self.grid = frequency_grid(cfg.plant.rate_hz, TUNE_GRID_POINTS)
        # COBYQA re-reads the constraints of earlier points (merit updates): keep them all
        self._cache: dict[tuple[float, ...], Evaluation] = {}
        self.evaluations = 0
        self.budget = math.inf  # distinct evaluations allowed (set by :func:`tune`)
        bad = [a for a in order if a not in self.axes]
        if bad:
            raise DcsmsError(f"order axes {', '.join(bad)}: the table has {', '.join(self.axes)}")
        self.order = list(order)
        if not order_gap >= 1.0:
            raise DcsmsError(f"order gap {order_gap}: must be >= 1")
        self.order_gap = order_gap
        self.rows = (["DFBC+FFC"] if objective == "attenuation" else list(self.target))
        if self.order:
            self.rows = list(dict.fromkeys([*self.rows, *ORDER]))

    def start(self) -> Array:
        """The starting configuration's knob values in unit coordinates (clipped to the knobs'
        ranges: :meth:`clipped` says which)."""
        return np.array([k.to_unit(_get(self.cfg, k)) for k in self.knobs])

    def clipped(self) -> list[tuple[Knob, float, float]]:
        """Knobs whose starting value lies outside their range: (knob, value, where it starts)."""
        out = []
        for k in self.knobs:
            v = _get(self.cfg, k)
            if not k.lo <= v <= k.hi:
                out.append((k, v, k.from_unit(k.to_unit(v))))
        return out

    def config(self, u: Sequence[float] | Array) -> SystemConfig:
        """The configuration at unit coordinates ``u``."""
        return apply(self.cfg, self.knobs, [k.from_unit(x) for k, x in zip(self.knobs, u,
                                                                           strict=True)])

    def evaluate(self, u: Sequence[float] | Array) -> Evaluation:
        """Judge the candidate at ``u`` (cached for repeated calls)."""
        key = tuple(float(x) for x in u)
        if key not in self._cache:
            if self.evaluations >= self.budget:
                raise _BudgetSpent
            self.evaluations += 1
            self._cache[key] = judge(self.config(key), self.axes, self.rows, self.objective,
                                     self.target, self.min_gm, self.min_pm, self.grid,
                                     self.order, self.order_gap)
        return self._cache[key]


def judge(cfg: SystemConfig, axes: Sequence[str], rows: Sequence[str], objective: str,
          target: Mapping[str, Mapping[str, float]], min_gm: float, min_pm: float,
          grid: Array | None = None, order: Sequence[str] = (),
          order_gap: float = ORDER_GAP) -> Evaluation:
    """Objective, constraint slacks and predicted Table-4 rows of one configuration."""
    slack_stab, gms, pms, dms = math.inf, [math.inf], [math.inf], math.inf
    for mode in _loop_sets(cfg).values():
        m = loop_model(cfg, mode)
        growth = float(np.max(np.log(np.abs(poles(m))))) * m.fs  # 1/s
        slack_stab = min(slack_stab, -growth)
        ol = OpenLoops(cfg, mode)
        loops, disks = margins(cfg, mode, grid, ol)
        gms += [abs(x.gm_db) for x in loops] + [d.gm_db for d in disks]
        pms += [x.pm_deg for x in loops] + [d.pm_deg for d in disks]
        dms = min(dms, smallest_delay(loops, delay_margins(cfg, mode, grid, ol))[1])
    force = math.inf
    for mode in ALL_MODES:
        if not mode.controllers:
            continue
        lm = shaped(cfg, loop_model(cfg, mode))
        f = rms(lm, lm.outputs["force"])
        limits = actuator_limits(cfg)[1]
        # an unstable mode has no stationary force: a finite slack keeps the search going
        force = min(force, max(float(np.min(1.0 - PEAK_FACTOR * f / limits)), -10.0))
    gm, pm = min(gms), min(pms)
    # no feedback loop reaches unit gain (margin inf): a finite slack for the search
    delay = min(dms / (DELAY_BUFFER * cfg.control.input_timeout_s) - 1.0, 10.0)
    slacks = {"stable": slack_stab, "gain margin": (gm - min_gm) / min_gm,
              "phase margin": (pm - min_pm) / min_pm, "delay margin": delay, "force": force}
    ref = TopVelocity(cfg, Mode.PASSIVE)
    f_r = resonances(ref, axes)
    base = {a: float(band_rms(ref, f_r[a], TUNE_BAND_POINTS)[j]) for j, a in enumerate(axes)}
    table: dict[str, dict[str, float]] = {}
    for label in rows:
        top = TopVelocity(cfg, next(m for m in ALL_MODES if m.label == label))
        table[label] = {a: float(band_rms(top, f_r[a], TUNE_BAND_POINTS)[j]) / base[a]
                        for j, a in enumerate(axes)}
    for a in order:
        slacks[f"order {a}"] = min(math.log(table[hi][a] / table[lo][a]) - math.log(order_gap)
                                   for hi, lo in itertools.pairwise(ORDER))
    if objective == "attenuation":
        logs = np.array([math.log(table["DFBC+FFC"][a]) for a in axes])
        obj = float(np.logaddexp.reduce(SOFTMAX * logs) / SOFTMAX)
    else:
        obj = float(sum(math.log(table[m][a] / t) ** 2 for m, row in target.items()
                        for a, t in row.items()))
    return Evaluation(obj, slacks, gm, pm, table)


class _BudgetSpent(Exception):
    """The search asked for more distinct model evaluations than it was given."""


@dataclass
class Result:
    """Outcome of :func:`tune`: the best feasible configuration (or the best found), its
    evaluation, the knob values and the number of model evaluations."""

    cfg: SystemConfig
    evaluation: Evaluation
    values: dict[str, float]
    evaluations: int
    iterations: int


def tune(problem: Problem, max_evaluations: int = 300,
         progress: Callable[[int, Evaluation], None] | None = None) -> Result:
    """Search the knobs (module docstring) from the starting configuration.

    Returns the best feasible candidate seen; if none was feasible, the one with the largest
    worst slack (the caller reports it as infeasible).
    """
    best: list[tuple[float, Array, Evaluation]] = []
    iterations = [0]

    def score(u: Array) -> tuple[float, float]:
        ev = problem.evaluate(u)
        worst = min(ev.slacks.values())
        return (ev.objective if ev.feasible else math.inf), worst

    def fun(u: Array) -> float:
        ev = problem.evaluate(u)
        s, worst = score(u)
        key = s if math.isfinite(s) else 1e6 - worst
        if not best or key < best[0][0]:
            best[:] = [(key, np.array(u, dtype=float), ev)]
        return ev.objective

    def cons(u: Array) -> Array:
        return np.array(list(problem.evaluate(u).slacks.values()))

    def callback(intermediate_result: Any) -> None:
        iterations[0] += 1
        if progress is not None and best:
            progress(iterations[0], best[0][2])

    u0 = problem.start()
    problem.budget = problem.evaluations + max_evaluations
    # COBYQA's maxfev counts objective calls; it also asks for constraints at other points, so
    # the budget of distinct model evaluations is enforced here
    with contextlib.suppress(_BudgetSpent):
        optimize.minimize(fun, u0, method="COBYQA", bounds=optimize.Bounds(0.0, 1.0),
                          constraints=optimize.NonlinearConstraint(cons, 0.0, np.inf),
                          callback=callback,
                          options={"maxfev": max_evaluations, "initial_tr_radius": 0.15,
                                   "final_tr_radius": 1e-4})
    _, u, ev = best[0]
    cfg = problem.config(u)
    values = {k.label: k.from_unit(x) for k, x in zip(problem.knobs, u, strict=True)}
    return Result(cfg, ev, values, problem.evaluations, iterations[0])


__all__ = ["OBJECTIVES", "ORDER", "ORDER_GAP", "Evaluation", "Knob", "Problem", "Result",
           "apply", "default_knobs", "judge", "tune"]
