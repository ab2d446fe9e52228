"""Stability margins of the running loop: loop-at-a-time and per-stage disk margins.

Every feedback path (controller, axis) is opened at the controller's output with
:class:`.loop_model.Break`, giving the open-loop transfer matrix ``G`` from the break inputs to
the controller outputs (``return = G break``; the loop closes with ``break = return``). With the
paths ``J`` open and every other closed, the loop gain in the negative-feedback convention is

    L_J = -[G_JJ + G_Jo (I - G_oo)^-1 G_oJ]

Loop-at-a-time margins use one path at a time (gain margin: the distance in dB of the nearest
crossing of the negative real axis from -1; phase margin: the smallest angular distance from -1
at a gain crossover). The disk margin of a stage opens all of its feedback paths at once and
bounds the structured singular value of the balanced sensitivity ``S - I/2``, ``S = (I + L)^-1``,
over independent complex perturbations of each path (D-scaled upper bound, as
``control.disk_margins`` does with slycot's AB13MD; equal to it for one path). Feedforward is no
loop: it stays closed. Frequencies in Hz.

The delay margin of a set of paths is the smallest extra delay ``tau`` (s), the same on every
path of the set, at which the loop reaches the edge of stability: ``det(I + e^{-j w tau} L_J)
= 0``, so some eigenvalue ``lam`` of ``L_J`` has ``|lam| = 1`` at ``w`` and
``tau = ((arg lam + pi) mod 2 pi) / w`` (one path: its gain crossovers). A real-time graph
delays a force by up to ``control.input_timeout_s`` (the plant ages it from the sample it
answers), so that timeout must stay below every margin: each path alone, each controller's
paths together (one late node) and all paths together (a slow machine).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import make_controller
from dcsms_ros.core.loop_model import Break, LoopModel, Response, loop_model
from dcsms_ros.core.model import axis_names
from dcsms_ros.core.modes import ControllerId, Mode, enabled_controllers, feedback_ids
from dcsms_ros.core.solvers import brent_root, nelder_mead

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

#: Frequency grid points (log-spaced from :data:`F_MIN_HZ` to just below Nyquist).
GRID_POINTS = 1500
F_MIN_HZ = 0.01


@dataclass(frozen=True)
class LoopMargin:
    """Margins of one feedback path: ``gm_db`` (inf: the phase never reaches -180 deg),
    ``pm_deg`` (inf: no gain crossover), read at ``wp_hz`` (phase crossover) and ``wg_hz``
    (gain crossover), Hz."""

    controller: str
    axis: str
    gm_db: float
    pm_deg: float
    wg_hz: float
    wp_hz: float
    #: extra delay of this path alone that makes the loop marginal, s (inf: no crossover)
    delay_s: float = math.inf


@dataclass(frozen=True)
class DelayMargin:
    """The smallest delay ``delay_s`` (s) added to every path in ``paths`` at once that makes
    the loop marginal, reached at ``f_hz`` (Hz; nan when no eigenvalue of the loop gain
    reaches unit modulus: ``delay_s`` is then inf)."""

    name: str
    paths: tuple[str, ...]
    delay_s: float
    f_hz: float


@dataclass(frozen=True)
class DiskMargin:
    """Disk margin of every feedback path of one stage opened together: ``alpha`` (size of
    the disk), the gain (dB, both ways) and phase (deg) variations it tolerates in all paths
    at once, and the frequency (Hz) where it is smallest."""

    stage: int
    paths: tuple[str, ...]
    alpha: float
    gm_db: float
    pm_deg: float
    f_hz: float


def feedback_breaks(cfg: SystemConfig, mode: Mode) -> list[Break]:
    """Every active feedback path of ``mode``: (fb_stage<i>, axis) with a non-zero gain."""
    on = enabled_controllers(mode, cfg.plant.num_stages)
    out = []
    for cid in feedback_ids(cfg.plant.num_stages):
        if cid in on:
            out += [Break(cid, int(a)) for a in make_controller(cfg, cid, enabled=True).axes]
    return out


def frequency_grid(fs: float, points: int = GRID_POINTS) -> Array:
    """Log-spaced frequencies (Hz) from :data:`F_MIN_HZ` to 0.999 of Nyquist."""
    return np.geomspace(F_MIN_HZ, 0.999 * fs / 2.0, points)


class OpenLoops:
    """The open-loop matrix ``G`` of a mode's feedback paths, and loop gains from it.

    Parameters
    ----------
    cfg : SystemConfig
    mode : Mode
    """

    def __init__(self, cfg: SystemConfig, mode: Mode) -> None:
        self.cfg = cfg
        self.breaks = feedback_breaks(cfg, mode)
        self.names = [f"{b.controller}.{axis_names(cfg.plant.dof)[b.axis]}"
                      for b in self.breaks]
        self.model: LoopModel | None = (loop_model(cfg, mode, self.breaks).select(
            "break", "return") if self.breaks else None)
        self._resp = Response(self.model) if self.model is not None else None

    def g(self, f_hz: Array) -> CArray:
        """``G`` at ``f_hz``, shape (F, n_paths, n_paths)."""
        assert self._resp is not None
        return self._resp(f_hz)

    def loop_gain(self, g: CArray, open_: Sequence[int]) -> CArray:
        """``L_J`` for the open paths ``open_`` from ``G`` values, shape (F, |J|, |J|)."""
        j = list(open_)
        o = [i for i in range(g.shape[1]) if i not in j]
        gjj = g[:, j][:, :, j]
        if not o:
            return np.asarray(-gjj)
        eye = np.eye(len(o))
        x = np.linalg.solve(eye[None] - g[:, o][:, :, o], g[:, o][:, :, j])
        return np.asarray(-(gjj + g[:, j][:, :, o] @ x))

    def siso(self, index: int) -> Callable[[Array], CArray]:
        """``f_hz -> L`` of one path (others closed)."""
        return lambda f: self.loop_gain(self.g(np.atleast_1d(f)), [index])[:, 0, 0]

    def stage_paths(self) -> dict[int, list[int]]:
        """Indices of each stage's feedback paths."""
        out: dict[int, list[int]] = {}
        for i, b in enumerate(self.breaks):
            out.setdefault(ControllerId.parse(b.controller).stage, []).append(i)
        return out


def _refine(fun: Callable[[float], float], f: Array, values: Array) -> list[float]:
    """Roots of ``fun`` bracketed by sign changes of ``values`` on the grid ``f``."""
    roots = []
    s = np.sign(values)
    for k in np.nonzero(s[:-1] * s[1:] < 0)[0]:
        try:
            roots.append(float(brent_root(fun, f[k], f[k + 1], xtol=1e-9 * f[k])))
        except ValueError:
            roots.append(float(0.5 * (f[k] + f[k + 1])))
    return roots


def siso_margins(lfun: Callable[[Array], CArray], f: Array,
                 values: CArray | None = None) -> tuple[float, float, float, float]:
    """(gm_db, pm_deg, wg_hz, wp_hz) of a loop gain given as ``f_hz -> L`` (negative-feedback
    convention), searched on the grid ``f`` and refined between grid points."""
    lv = lfun(f) if values is None else values

    def one(x: float) -> complex:
        return complex(lfun(np.array([x]))[0])

    gm_db, wp = math.inf, math.nan
    # phase crossovers: Im L = 0 with Re L < 0
    for fc in _refine(lambda x: one(x).imag, f, lv.imag):
        v = one(fc)
        if v.real < 0 and abs(v) > 0:
            db = -20.0 * math.log10(abs(v))
            if abs(db) < abs(gm_db):
                gm_db, wp = db, fc
    pm, wg = math.inf, math.nan
    for fc in _refine(lambda x: abs(one(x)) - 1.0, f, np.abs(lv) - 1.0):
        p = 180.0 - abs(math.degrees(np.angle(one(fc))))
        if p < pm:
            pm, wg = p, fc
    return gm_db, pm, wg, wp


def _delay_at(lam: complex, f_hz: float) -> float:
    """Delay (s) that turns the loop-gain value ``lam`` (|lam| = 1) at ``f_hz`` onto -1."""
    rot = (math.atan2(lam.imag, lam.real) + math.pi) % (2.0 * math.pi)
    return rot / (2.0 * math.pi * f_hz)


def delay_margin(lfun: Callable[[Array], CArray], f: Array, values: CArray | None = None
                 ) -> tuple[float, float]:
    """(delay_s, f_hz) of a loop gain given as ``f_hz -> L`` (shape (F,) or (F, m, m)),
    searched on the grid ``f``: every frequency where an eigenvalue of ``L`` crosses unit
    modulus (the k-th largest modulus is continuous in f, so each crossing is bracketed on
    the grid and refined), the smallest delay that moves it onto -1."""
    lv = lfun(f) if values is None else values

    def eig(x: CArray) -> CArray:
        v = np.asarray(x)
        return (np.linalg.eigvals(v) if v.ndim == 3 else v[:, None]).astype(complex)

    mods = -np.sort(-np.abs(eig(lv)), axis=1)
    best, where = math.inf, math.nan
    for k in range(mods.shape[1]):
        def kth(x: float, k: int = k) -> float:
            return float(-np.sort(-np.abs(eig(lfun(np.array([x])))[0]))[k] - 1.0)

        for fc in _refine(kth, f, mods[:, k] - 1.0):
            lam = eig(lfun(np.array([fc])))[0]
            one = lam[int(np.argmin(np.abs(np.abs(lam) - 1.0)))]
            tau = _delay_at(complex(one), fc)
            if tau < best:
                best, where = tau, fc
    return best, where


def _mu_upper(m: CArray) -> float:
    """D-scaled upper bound of the structured singular value of ``m`` (m x m) over
    independent complex scalars on the diagonal: ``min_D sigma_max(D m D^-1)``."""
    n = m.shape[0]
    top = float(np.linalg.norm(m, 2))
    if n == 1:
        return top

    def smax(x: Array) -> float:
        d = np.exp(np.concatenate([[0.0], x]))
        return float(np.linalg.norm((d[:, None] * m) / d[None, :], 2))

    # start from the Osborne scaling that balances |m|'s rows and columns (close to optimal)
    _, (scale, _) = scipy.linalg.matrix_balance(np.abs(m), permute=False, separate=True)
    x0 = np.log(scale[0] / scale[1:]) if np.all(scale > 0) else np.zeros(n - 1)
    _, best = nelder_mead(smax, x0, xatol=1e-5, fatol=1e-7 * max(top, 1e-300),
                          maxiter=200 * n)
    return min(top, smax(x0), best)


def disk_from_alpha(alpha: float) -> tuple[float, float]:
    """(gain margin dB, phase margin deg) of a balanced disk of size ``alpha``."""
    if alpha >= 2.0:
        return math.inf, 90.0
    gmin = (1.0 - alpha / 2.0) / (1.0 + alpha / 2.0)
    gmax = 1.0 / gmin
    pm = math.degrees(math.acos(min(1.0, 2.0 / (gmin + gmax))))
    return 20.0 * math.log10(gmax), pm


def disk_margin(l_values: CArray, f: Array) -> tuple[float, float]:
    """(alpha, f_hz) of a loop gain sampled on ``f``: shape (F,) or (F, m, m)."""
    lv = l_values.reshape(l_values.shape[0], *(l_values.shape[1:] or (1, 1)))
    m = lv.shape[1]
    eye = np.eye(m)
    bal = np.linalg.inv(eye[None] + lv) - 0.5 * eye[None]
    upper = np.linalg.norm(bal, 2, axis=(1, 2))
    best, where = 0.0, math.nan
    for k in np.argsort(-upper):
        if upper[k] <= best:
            break  # mu <= sigma_max: no later frequency can beat the bound found
        mu = _mu_upper(bal[k])
        if mu > best:
            best, where = mu, float(f[k])
    return (math.inf if best == 0.0 else 1.0 / best), where


def smallest_delay(loops: Sequence[LoopMargin], delays: Sequence[DelayMargin]
                   ) -> tuple[str, float]:
    """(paths, s) of the smallest delay margin of any path alone or group of paths
    (``("-", inf)``: no feedback, or no loop gain reaches unit modulus)."""
    cands = [(f"{m.controller}.{m.axis}", m.delay_s) for m in loops]
    cands += [(d.name, d.delay_s) for d in delays]
    return min(cands, key=lambda c: c[1], default=("-", math.inf))


def _open(cfg: SystemConfig, mode: Mode, f_hz: Array | None, loops_: OpenLoops | None
          ) -> tuple[OpenLoops, Array, CArray] | None:
    """The open loops, the search grid and ``G`` on it (None: no feedback path)."""
    ol = OpenLoops(cfg, mode) if loops_ is None else loops_
    if ol.model is None:
        return None
    f = frequency_grid(cfg.plant.rate_hz) if f_hz is None else np.asarray(f_hz, float)
    return ol, f, ol.g(f)


def margins(cfg: SystemConfig, mode: Mode, f_hz: Array | None = None,
            loops_: OpenLoops | None = None) -> tuple[list[LoopMargin], list[DiskMargin]]:
    """Loop-at-a-time margins of every feedback path and the disk margin of every stage.

    Parameters
    ----------
    cfg : SystemConfig
    mode : Mode
    f_hz : ndarray, optional
        Search grid (default :func:`frequency_grid`).
    loops_ : OpenLoops, optional
        The mode's open loops when already built.
    """
    got = _open(cfg, mode, f_hz, loops_)
    if got is None:
        return [], []
    ol, f, g = got
    loops = []
    for i, b in enumerate(ol.breaks):
        lv = ol.loop_gain(g, [i])[:, 0, 0]
        gm, pm, wg, wp = siso_margins(ol.siso(i), f, lv)
        tau, _ = delay_margin(ol.siso(i), f, lv)
        loops.append(LoopMargin(b.controller, axis_names(cfg.plant.dof)[b.axis], gm, pm, wg,
                                wp, tau))
    disks = []
    for stage, idx in ol.stage_paths().items():
        alpha, fw = disk_margin(ol.loop_gain(g, idx), f)
        gm, pm = disk_from_alpha(alpha)
        disks.append(DiskMargin(stage, tuple(ol.names[i] for i in idx), alpha, gm, pm, fw))
    return loops, disks


def delay_margins(cfg: SystemConfig, mode: Mode, f_hz: Array | None = None,
                  loops_: OpenLoops | None = None) -> list[DelayMargin]:
    """Delay margins of each controller's feedback paths together (one late node; the other
    loops closed and on time) and of all feedback paths together (name ``all``); parameters
    as :func:`margins`."""
    got = _open(cfg, mode, f_hz, loops_)
    if got is None:
        return []
    ol, f, g = got
    groups: dict[str, list[int]] = {}
    for i, b in enumerate(ol.breaks):
        groups.setdefault(b.controller, []).append(i)
    if len(groups) > 1:
        groups["all"] = list(range(len(ol.breaks)))
    out = []
    for name, idx in groups.items():
        def lfun(x: Array, idx: list[int] = idx) -> CArray:
            return ol.loop_gain(ol.g(np.atleast_1d(x)), idx)

        tau, fw = delay_margin(lfun, f, ol.loop_gain(g, idx))
        out.append(DelayMargin(name, tuple(ol.names[i] for i in idx), tau, fw))
    return out


def late_force_reason(cfg: SystemConfig, mode: Mode, late_s: float | None = None
                      ) -> str | None:
    """None when ``mode`` stays stable with forces up to ``late_s`` s late (default
    ``control.input_timeout_s``: how late a real-time plant applies a force), one controller's
    or all of them (:func:`delay_margins`: a controller's axes travel in one message, so its
    paths are late together); else a one-line reason naming the smallest margin."""
    late = cfg.control.input_timeout_s if late_s is None else late_s
    dms = delay_margins(cfg, mode)
    if not dms:
        return None
    worst = min(dms, key=lambda d: d.delay_s)
    if worst.delay_s > late:
        return None
    return (f"{mode.label} goes unstable with forces {late * 1e3:g} ms late "
            f"(control.input_timeout_s): the delay margin of {worst.name} is "
            f"{worst.delay_s * 1e3:.1f} ms at {worst.f_hz:.1f} Hz")


__all__ = ["DelayMargin", "DiskMargin", "LoopMargin", "OpenLoops", "delay_margin",
           "delay_margins", "disk_from_alpha", "disk_margin", "feedback_breaks",
           "frequency_grid", "late_force_reason", "margins", "siso_margins",
           "smallest_delay"]
