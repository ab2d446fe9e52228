"""Issue 22's scenario for the analysis tests: the preset's own floor with a burst, and the
supervisor as the engine takes it (fresh for every run)."""

from __future__ import annotations

import numpy as np

from dcsms_ros.core.check import unstable_reason
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.floor import floor_gain
from dcsms_ros.core.modes import ALL_MODES, Mode
from dcsms_ros.core.supervisor import Supervisor, SupervisorSettings


def burst_floor(cfg: SystemConfig, duration_s: float, start_s: float, end_s: float,
                factor: float = 3000.0) -> np.ndarray:
    """The true ground twist of a Passive run (m/s, shape (K, dof)), x ``factor`` from
    ``start_s`` to ``end_s``."""
    ground = simulate(cfg, Mode.PASSIVE, duration_s + 1.0, trip=False).truth[:, 0].copy()
    fs = cfg.plant.rate_hz
    ground[int(start_s * fs):int(end_s * fs)] *= factor
    return np.asarray(ground)


def supervisor(cfg: SystemConfig, mode: Mode) -> Supervisor:
    """Default settings, the floor gains and the stability guard of ``cfg``."""
    return Supervisor(SupervisorSettings(), mode,
                      band_gain={m: floor_gain(cfg, m) for m in ALL_MODES},
                      stable=lambda m: unstable_reason(cfg, m) is None)
