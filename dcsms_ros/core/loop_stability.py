"""Is the loop as it runs stable? The poles of the discrete closed loop (:mod:`.loop_model`).

This is the verdict the stability guard of the running graph asks for at start and on every
switch or retuning; it needs numpy and ``scipy.linalg`` only, so a node that holds the guard
does not import python-control (:mod:`.check` adds margins and predicted forces for the CLI).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.loop_model import loop_model, poles, s_plane
from dcsms_ros.core.modes import Mode


@dataclass(frozen=True)
class Stability:
    """Poles of the discrete closed loop: ``worst`` is the pole of largest ``|z|``;
    ``s_hz`` maps poles to ``fs ln(z) / 2 pi`` (Hz, as the paper prints eigenvalues)."""

    stable: bool
    worst_z: complex
    worst_s_hz: complex
    unstable_s_hz: tuple[complex, ...]

    @property
    def growth_per_s(self) -> float:
        """Exponential growth (> 0) or decay (< 0) rate of the worst pole, 1/s."""
        return 2.0 * math.pi * self.worst_s_hz.real


def stability(cfg: SystemConfig, mode: Mode) -> Stability:
    """Poles of ``mode``'s loop as it runs."""
    m = loop_model(cfg, mode)
    z = poles(m)
    s = s_plane(z, m.fs) / (2.0 * math.pi)
    i = int(np.argmax(np.abs(z)))
    bad = np.abs(z) >= 1.0
    order = np.argsort(-np.abs(z[bad]))
    return Stability(not bool(bad.any()), complex(z[i]), complex(s[i]),
                     tuple(complex(x) for x in s[bad][order]))


def unstable_reason(cfg: SystemConfig, mode: Mode) -> str | None:
    """None when ``mode`` is stable as it runs, else a one-line reason naming the pole."""
    st = stability(cfg, mode)
    if st.stable:
        return None
    p = st.worst_s_hz
    return (f"{mode.label} is unstable with this configuration: closed-loop pole at "
            f"{p.real:+.4f} {p.imag:+.4f}j Hz (growth {st.growth_per_s:.3g} /s)")


__all__ = ["Stability", "stability", "unstable_reason"]
