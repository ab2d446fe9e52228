"""How long after a mode switch the analysis waits: until the new loop's transient has decayed
in the band Table 4 integrates over.

A switch fades the gains over ``control.fade_time_s``; what it sets ringing then decays with
the closed-loop poles of the new mode. Only poles near the analysed band matter: the band is one
third of an octave around the Passive resonance, and a Hann-windowed Welch estimate does not
see a transient an octave away (the TEM's rocking modes at 0.4-0.5 Hz, time constant 23 s, and
the 0.02 Hz sensor extension, 11 s, leave a 2-2.5 Hz band untouched). So the drop is the fade
plus :data:`TIME_CONSTANTS` times the slowest time constant among the poles within
:data:`POLE_BAND_OCT` of a table axis' resonance (amplitude down to e^-3 = 5 %, energy 0.25 %),
and at least :data:`.segments.SETTLE_S`. A mode the model calls unstable keeps
:data:`.segments.SETTLE_S`: its growth is what the segment must show.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from dcsms_ros.analysis.predict import TopVelocity, resonances, table_axes
from dcsms_ros.analysis.segments import SETTLE_S
from dcsms_ros.core.check import loop_poles
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import Mode

#: Time constants waited after the fade.
TIME_CONSTANTS = 3.0
#: Poles this far (octaves) from a resonance count as in the band.
POLE_BAND_OCT = 1.0


def band_time_constant(cfg: SystemConfig, mode: Mode, resonance_hz: Sequence[float]) -> float:
    """The slowest decay time (s) of ``mode``'s closed-loop poles within
    :data:`POLE_BAND_OCT` of any of ``resonance_hz`` (Hz); 0 when none is near (inf when one
    does not decay)."""
    slowest = 0.0
    for p in loop_poles(cfg, mode):
        f = abs(p.s_hz.imag)
        if not any(abs(math.log2(max(f, 1e-12) / fr)) <= POLE_BAND_OCT for fr in resonance_hz):
            continue
        decay = -2.0 * math.pi * p.s_hz.real  # 1/s
        slowest = max(slowest, 1.0 / decay if decay > 0 else math.inf)
    return slowest


def settle_times(cfg: SystemConfig, modes: Sequence[Mode]) -> dict[str, tuple[float, float]]:
    """Per mode label: (seconds to drop after switching into it, the in-band time constant s)."""
    f_r = list(resonances(TopVelocity(cfg, Mode.PASSIVE), table_axes(cfg)).values())
    out = {}
    for m in modes:
        if any(p.s_hz.real >= 0.0 for p in loop_poles(cfg, m)):
            # an unstable loop has no transient that ends: keep the growth the segment shows
            out[m.label] = (SETTLE_S, math.inf)
            continue
        tau = band_time_constant(cfg, m, f_r)
        out[m.label] = (max(SETTLE_S, cfg.control.fade_time_s + TIME_CONSTANTS * tau), tau)
    return out


__all__ = ["POLE_BAND_OCT", "TIME_CONSTANTS", "band_time_constant", "settle_times"]
