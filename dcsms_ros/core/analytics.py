"""Analytic side of the cascade (python-control): the paper's Eq. 4 and Eq. 10, closed-loop
transmissibility built from the state-space plant and the very filters the loops run, modes,
Routh-Hurwitz and loop margins. Frequencies in Hz, velocities in m/s, forces in N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import control as ct
import numpy as np

from dcsms_ros.core.closed_loop import (
    AXIS_INDEX,
    Link,
    axis_index,
    closed_loop_ss,
    controller_links,
    siso,
)
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.lti import Array, CArray, freq_response, num_den
from dcsms_ros.core.model import plant_state_space
from dcsms_ros.core.modes import FEEDBACK, Mode
from dcsms_ros.core.routh import RouthResult, characteristic_polynomial, routh

TF = Any  # control.TransferFunction (python-control ships no type stubs)

__all__ = [
    "AXIS_INDEX", "Margins", "ModalInfo", "RouthResult", "characteristic_polynomial",
    "closed_loop_ss", "eq4_tf", "eq10_stage1_tf", "eq10_tf", "freq_response", "is_stable",
    "loop_margins", "margins", "modes", "routh", "stage_locked_frequency", "transmissibility",
    "uncoupled_frequencies",
]


# ---------------------------------------------------------------------------------------------
# The paper's closed forms (two stages, vertical)


def eq4_tf(m1: float, m2: float, c1: float, c2: float, k1: float, k2: float) -> TF:
    """Passive ground-to-stage-2 velocity transmissibility ``v_p2/v_b`` (paper Eq. 4).

    ``Z1 Z2 / [(m2 s + Z2)(m1 s + Z1) + m2 s Z2]`` with ``Z_i = c_i + k_i/s``, multiplied through
    by ``s^2`` so the denominator is the characteristic polynomial (no cancelling ``s``).
    Masses in kg, damping in N*s/m, stiffness in N/m; dimensionless result.
    """
    num = np.polymul([c2, k2], [c1, k1])
    den = np.polyadd(np.polymul([m2, c2, k2], [m1, c1, k1]), np.polymul([m2, 0.0, 0.0], [c2, k2]))
    return ct.tf(num, den)


def _eq10_polys(m1: float, m2: float, c1: float, c2: float, k1: float, k2: float,
                h1fbc: Any, h2fbc: Any, h1ffc: Any, h2ffc: Any) -> tuple[Array, Array, Array]:
    """(num of v_p1/v_b, num of v_p2/v_b, common den) after multiplying Eq. 10 by
    ``Q1 Q2``, ``Q_i = s * den(H_ifbc) * den(H_iffc)``, which clears every fraction."""
    n1b, d1b = num_den(h1fbc)
    n1f, d1f = num_den(h1ffc)
    n2b, d2b = num_den(h2fbc)
    n2f, d2f = num_den(h2ffc)
    pm, s = np.polymul, [1.0, 0.0]
    q1 = pm(s, pm(d1b, d1f))
    # A_i = (Z_i - H_iffc) Q_i, B_i = (m_i s + Z_i + H_ifbc) Q_i
    a1: Array = np.polysub(pm([c1, k1], pm(d1b, d1f)), pm(s, pm(n1f, d1b)))
    b1: Array = np.polyadd(pm([m1, c1, k1], pm(d1b, d1f)), pm(s, pm(n1b, d1f)))
    a2: Array = np.polysub(pm([c2, k2], pm(d2b, d2f)), pm(s, pm(n2f, d2b)))
    b2: Array = np.polyadd(pm([m2, c2, k2], pm(d2b, d2f)), pm(s, pm(n2b, d2f)))
    den: Array = np.polyadd(pm(b1, b2), pm([m2, 0.0], pm(a2, q1)))
    return pm(a1, b2), pm(a1, a2), den


def eq10_tf(m1: float, m2: float, c1: float, c2: float, k1: float, k2: float,
            h1fbc: Any = 0.0, h2fbc: Any = 0.0, h1ffc: Any = 0.0, h2ffc: Any = 0.0) -> TF:
    """Active ``v_p2/v_b`` (NOTES.md, re-derived Eq. 10).

    ``(Z2 - H2ffc)(Z1 - H1ffc) / [(m1 s + Z1 + H1fbc)(m2 s + Z2 + H2fbc) + m2 s (Z2 - H2ffc)]``.

    Parameters
    ----------
    m1, m2 : float
        Stage masses, kg.
    c1, c2 : float
        Suspension damping, N*s/m.
    k1, k2 : float
        Suspension stiffness, N/m.
    h1fbc, h2fbc : float or control.TransferFunction
        Velocity feedback of stage 1 / 2, N/(m/s): ``u_i = -H_ifbc v_pi``.
    h1ffc, h2ffc : float or control.TransferFunction
        Feedforward of the velocity below the stage (ground / stage 1), N/(m/s).
    """
    _, num, den = _eq10_polys(m1, m2, c1, c2, k1, k2, h1fbc, h2fbc, h1ffc, h2ffc)
    return ct.tf(num, den)


def eq10_stage1_tf(m1: float, m2: float, c1: float, c2: float, k1: float, k2: float,
                   h1fbc: Any = 0.0, h2fbc: Any = 0.0, h1ffc: Any = 0.0,
                   h2ffc: Any = 0.0) -> TF:
    """Companion of :func:`eq10_tf`: ``v_p1/v_b = (Z1 - H1ffc)(m2 s + Z2 + H2fbc) / den``."""
    num, _, den = _eq10_polys(m1, m2, c1, c2, k1, k2, h1fbc, h2fbc, h1ffc, h2ffc)
    return ct.tf(num, den)


def stage_locked_frequency(cfg: SystemConfig) -> float:
    """``sqrt(k1 / (m1 + ... + mN)) / 2 pi`` in Hz: every stage locked onto stage 1 (vertical)."""
    st = cfg.plant.stages
    return math.sqrt(st[0].stiffness / sum(s.mass for s in st)) / (2.0 * math.pi)


def uncoupled_frequencies(cfg: SystemConfig) -> list[float]:
    """``sqrt(k_i / m_i) / 2 pi`` (Hz) of each stage on its own suspension, vertical."""
    return [math.sqrt(s.stiffness / s.mass) / (2.0 * math.pi) for s in cfg.plant.stages]


# ---------------------------------------------------------------------------------------------
# Closed loop


def transmissibility(cfg: SystemConfig, mode: Mode, axis: str | int = "z",
                     sensors: bool = False) -> list[TF]:
    """Ground-to-stage velocity transmissibility ``v_pi / v_b`` for i = 1..N along ``axis``.

    Built from :func:`model.plant_state_space` closed by the controllers of ``mode`` (their
    :mod:`.filters` transfer functions, on every axis); the ground moves along ``axis`` only.

    Parameters
    ----------
    cfg : SystemConfig
    mode : Mode
    axis : str or int
        ``x y z rx ry rz`` or 0..5; 1dof has only ``z``.
    sensors : bool
        Put the geophone and its low-frequency extension in every measured velocity.

    Returns
    -------
    list of control.TransferFunction
        N SISO functions, (m/s)/(m/s) or (rad/s)/(rad/s).
    """
    sys = closed_loop_ss(cfg, mode, sensors)
    dof = cfg.plant.dof
    a = axis_index(axis, dof)
    return [siso(sys, a, (i - 1) * dof + a) for i in range(1, cfg.plant.num_stages + 1)]


@dataclass(frozen=True)
class ModalInfo:
    """One oscillatory mode: ``eigenvalue_hz`` = eigenvalue / 2 pi (Hz, positive imaginary
    part), ``frequency_hz`` = |eigenvalue| / 2 pi (undamped natural frequency, Hz),
    ``damping_ratio`` = -Re / |eigenvalue|."""

    eigenvalue_hz: complex
    frequency_hz: float
    damping_ratio: float


def eigenvalues(cfg: SystemConfig, mode: Mode | None = None) -> CArray:
    """Eigenvalues (rad/s) of the passive plant (1dof: roots of the characteristic polynomial)
    or of the closed loop of ``mode`` (plant and controller states)."""
    if mode is None or mode is Mode.PASSIVE:
        if cfg.plant.dof == 1:
            return np.asarray(np.roots(characteristic_polynomial(cfg)), dtype=complex)
        return np.asarray(np.linalg.eigvals(plant_state_space(cfg).a), dtype=complex)
    return np.asarray(np.linalg.eigvals(closed_loop_ss(cfg, mode).A), dtype=complex)


def modes(cfg: SystemConfig, mode: Mode | None = None) -> list[ModalInfo]:
    """Oscillatory modes (one per complex-conjugate pair) sorted by frequency.

    Parameters
    ----------
    cfg : SystemConfig
    mode : Mode, optional
        Closed-loop modes of this control mode instead of the passive plant.
    """
    out = []
    for lam in eigenvalues(cfg, mode):
        r = abs(lam)
        if lam.imag > 1e-9 * max(r, 1.0):
            out.append(ModalInfo(complex(lam) / (2.0 * math.pi), float(r) / (2.0 * math.pi),
                                 float(-lam.real / r)))
    return sorted(out, key=lambda m: m.frequency_hz)


def is_stable(cfg: SystemConfig, mode: Mode | None = None) -> bool:
    """Asymptotic stability of the passive plant (1dof: Routh-Hurwitz on the characteristic
    polynomial) or of the closed loop of ``mode``."""
    if (mode is None or mode is Mode.PASSIVE) and cfg.plant.dof == 1:
        return routh(characteristic_polynomial(cfg)).stable
    return bool(np.all(eigenvalues(cfg, mode).real < 0.0))


@dataclass(frozen=True)
class Margins:
    """Stability margins of one loop: gain margin (dB; inf when the phase never crosses
    -180 deg), phase margin (deg), gain-crossover frequency ``wg_hz`` (|L| = 1, where the phase
    margin is read) and phase-crossover frequency ``wp_hz`` (where the gain margin is read), Hz."""

    gm_db: float
    pm_deg: float
    wg_hz: float
    wp_hz: float


def loop_gain(cfg: SystemConfig, mode: Mode, link: Link, sensors: bool = False) -> TF:
    """Loop gain ``L = K(s) P(s)`` of one feedback link broken at its actuator input, every other
    loop of ``mode`` closed; negative-feedback convention (the loop applies ``-K v``)."""
    sys = closed_loop_ss(cfg, mode, sensors, exclude=link)
    dof = cfg.plant.dof
    p = siso(sys, dof + link.dst, link.src)
    return ct.tf(*num_den(link.tf)) * p


def margins(loop: TF) -> Margins:
    """Margins of a loop gain (negative-feedback convention).

    The phase margin is the smallest angular distance of ``L(j w)`` from the -1 point over all
    gain crossovers, ``180 - |angle L|`` with the angle in (-180, 180]; python-control's
    unwrapped phase mislabels a velocity loop whose high-pass starts it near +180 deg. The gain
    margin is the phase crossover closest to instability (smallest ``|gm_db|``).
    """
    gm, _, _, wpc, wgc, _ = ct.stability_margins(loop, returnall=True)
    gm, wpc, wgc = (np.atleast_1d(np.asarray(x, dtype=float)) for x in (gm, wpc, wgc))
    gm_db, wp_hz = math.inf, math.nan
    ok = np.isfinite(gm) & (gm > 0)
    if np.any(ok):
        db = 20.0 * np.log10(gm[ok])
        j = int(np.argmin(np.abs(db)))
        gm_db, wp_hz = float(db[j]), float(wpc[ok][j]) / (2.0 * math.pi)
    pm_deg, wg_hz = math.inf, math.nan
    wgc = wgc[np.isfinite(wgc) & (wgc > 0)]
    if wgc.size:
        pms = 180.0 - np.abs(np.angle(freq_response(loop, wgc / (2.0 * math.pi)), deg=True))
        j = int(np.argmin(pms))
        pm_deg, wg_hz = float(pms[j]), float(wgc[j]) / (2.0 * math.pi)
    return Margins(gm_db, pm_deg, wg_hz, wp_hz)


def loop_margins(cfg: SystemConfig, mode: Mode, axis: str | int = "z",
                 sensors: bool = False) -> dict[str, Margins]:
    """Margins (:func:`margins`) of every enabled feedback loop of ``mode`` along ``axis``,
    each broken at its actuator with every other loop closed.

    Returns
    -------
    dict
        ``{controller id: Margins}`` for each ``fb_stage<i>`` active on that axis.
    """
    dof = cfg.plant.dof
    a = axis_index(axis, dof)
    return {link.controller: margins(loop_gain(cfg, mode, link, sensors))
            for link in controller_links(cfg, mode, sensors)
            if link.kind == FEEDBACK and link.dst % dof == a}
