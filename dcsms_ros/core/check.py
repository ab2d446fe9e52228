"""Is a configuration safe to run? Stability, margins and predicted actuator forces per mode.

Everything is judged on the loop that runs (:mod:`.loop_model`): the closed-loop poles
(:mod:`.loop_stability`), the
loop-at-a-time and per-stage disk margins (:mod:`.margins`) and the actuator forces predicted
from the configured disturbances (:mod:`.spectra`), whose peak is taken as 4 x RMS (a Gaussian
force exceeds it 0.006 % of the time) and compared with each actuator's limit. In real time the
plant applies a force up to ``control.input_timeout_s`` after the sample it answers, so that
timeout must stay below every delay margin (:func:`.margins.delay_margins`: each path alone,
each controller's paths, all paths together).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core import analytics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import actuator_limits
from dcsms_ros.core.loop_model import loop_model, pole_parts, s_plane
from dcsms_ros.core.loop_stability import Stability, stability, unstable_reason
from dcsms_ros.core.margins import (
    DelayMargin,
    DiskMargin,
    LoopMargin,
    OpenLoops,
    delay_margins,
    margins,
    smallest_delay,
)
from dcsms_ros.core.modes import ALL_MODES, Mode
from dcsms_ros.core.safety import MIN_GM_DB, MIN_PM_DEG, PEAK_FACTOR
from dcsms_ros.core.spectra import rms, shaped

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Pole:
    """One closed-loop pole: ``s_hz`` = eigenvalue / 2 pi (Hz; discrete: ``fs ln z / 2 pi``),
    ``z`` the discrete pole (``nan`` for a continuous model), ``part`` the part of the loop
    that participates most (``plant``, ``geophones``, ``extension``, a controller id)."""

    s_hz: complex
    z: complex
    part: str

    @property
    def frequency_hz(self) -> float:
        """Undamped natural frequency ``|s| / 2 pi``, Hz."""
        return abs(self.s_hz)

    @property
    def damping_ratio(self) -> float:
        """``-Re(s) / |s|`` (negative: growing)."""
        r = abs(self.s_hz)
        return -self.s_hz.real / r if r > 0 else 1.0

    @property
    def unstable(self) -> bool:
        return abs(self.z) >= 1.0 if math.isfinite(abs(self.z)) else self.s_hz.real > 0.0


def loop_poles(cfg: SystemConfig, mode: Mode) -> list[Pole]:
    """Every pole of ``mode``'s loop as it runs, largest ``|z|`` first."""
    m = loop_model(cfg, mode)
    z, parts = pole_parts(m)
    s = s_plane(z, m.fs) / (2.0 * math.pi)
    order = np.argsort(-np.abs(z), kind="stable")
    return [Pole(complex(s[i]), complex(z[i]), parts[i]) for i in order]


def ideal_poles(cfg: SystemConfig, mode: Mode) -> list[Pole]:
    """Every pole of ``mode`` on the paper's continuous model (ideal sensors, continuous
    controllers), largest real part first."""
    lam = analytics.eigenvalues(cfg, mode) / (2.0 * math.pi)
    return [Pole(complex(x), complex(math.nan, math.nan), "")
            for x in sorted(lam, key=lambda x: -x.real)]


def oscillatory(poles: list[Pole]) -> list[Pole]:
    """One entry per complex pair (positive imaginary part), lowest frequency first."""
    out = [p for p in poles if p.s_hz.imag > 1e-9 * max(abs(p.s_hz), 1.0)]
    return sorted(out, key=lambda p: p.frequency_hz)


@dataclass(frozen=True)
class ModeCheck:
    """Verdict on one mode; ``failures`` says why it is not safe (empty: safe)."""

    mode: Mode
    stability: Stability
    loops: list[LoopMargin]
    disks: list[DiskMargin]
    actuators: list[str]
    force_rms_n: Array
    force_limit_n: Array
    failures: list[str] = field(default_factory=list)
    delays: list[DelayMargin] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.failures

    @property
    def delay_s(self) -> tuple[str, float]:
        """(paths, s) of the smallest delay margin (:func:`.margins.smallest_delay`)."""
        return smallest_delay(self.loops, self.delays)

    @property
    def force_peak_n(self) -> Array:
        """Predicted peak force per actuator, N (:data:`PEAK_FACTOR` x RMS)."""
        return PEAK_FACTOR * self.force_rms_n


def check_mode(cfg: SystemConfig, mode: Mode, min_gm_db: float = MIN_GM_DB,
               min_pm_deg: float = MIN_PM_DEG) -> ModeCheck:
    """Judge one mode: stable, margins at least the minima, no predicted saturation."""
    st = stability(cfg, mode)
    ol = OpenLoops(cfg, mode)
    loops, disks = margins(cfg, mode, loops_=ol)
    delays = delay_margins(cfg, mode, loops_=ol)
    names, limit = actuator_limits(cfg)
    lm = shaped(cfg, loop_model(cfg, mode))
    force = rms(lm, lm.outputs["force"])
    fails = []
    if not st.stable:
        p = st.worst_s_hz
        fails.append(f"unstable: pole {p.real:+.4f} {p.imag:+.4f}j Hz (growth "
                     f"{st.growth_per_s:.3g} /s)")
    else:
        fails.extend(f"{lp.controller}.{lp.axis} margins {lp.gm_db:.1f} dB / "
                     f"{lp.pm_deg:.0f} deg below {min_gm_db:g} dB / {min_pm_deg:g} deg"
                     for lp in loops if abs(lp.gm_db) < min_gm_db or lp.pm_deg < min_pm_deg)
        fails.extend(f"stage{dk.stage} disk margin {dk.gm_db:.1f} dB / "
                     f"{dk.pm_deg:.0f} deg below {min_gm_db:g} dB / {min_pm_deg:g} deg"
                     for dk in disks if dk.gm_db < min_gm_db or dk.pm_deg < min_pm_deg)
        timeout = cfg.control.input_timeout_s
        name, tau = smallest_delay(loops, delays)
        if tau <= timeout:
            fails.append(f"delay margin of {name} {tau * 1e3:.1f} ms not above "
                         f"control.input_timeout_s {timeout * 1e3:g} ms (a real-time force "
                         "may be applied that late)")
        peak = PEAK_FACTOR * force
        over = [f"{n} {p:.3g} N > {lim:g} N" for n, p, lim in zip(names, peak, limit,
                                                                  strict=True) if p > lim]
        if over:
            fails.append("predicted saturation (peak = 4 x RMS): " + ", ".join(over))
    return ModeCheck(mode, st, loops, disks, names, force, limit, fails, delays)


def check_config(cfg: SystemConfig, modes: Sequence[Mode] = ALL_MODES,
                 min_gm_db: float = MIN_GM_DB, min_pm_deg: float = MIN_PM_DEG
                 ) -> list[ModeCheck]:
    """:func:`check_mode` for each of ``modes`` (default all six)."""
    return [check_mode(cfg, m, min_gm_db, min_pm_deg) for m in modes]


__all__ = ["MIN_GM_DB", "MIN_PM_DEG", "PEAK_FACTOR", "ModeCheck", "Pole", "Stability",
           "actuator_limits", "check_config", "check_mode", "ideal_poles", "loop_poles",
           "oscillatory", "stability", "unstable_reason"]
