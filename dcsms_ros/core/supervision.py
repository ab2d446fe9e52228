"""A table's supervisor built from its configuration: the settings of ``supervisor.*``, the
loop model's floor gains and the model's stability verdict, both computed on first use (a run
that is never loud never pays for them). The batch engine and the mode-switch node build it
the same way, so they take the same decisions.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.floor import floor_gain
from dcsms_ros.core.loop_stability import unstable_reason
from dcsms_ros.core.modes import ALL_MODES, Mode, parse_mode
from dcsms_ros.core.supervisor import Supervisor, SupervisorSettings

Array = NDArray[np.float64]


def settings_from(cfg: SystemConfig) -> SupervisorSettings:
    """:class:`SupervisorSettings` of ``cfg.supervisor``; the trip threshold is
    ``control.trip_rms_mps``."""
    s = cfg.supervisor
    return SupervisorSettings(
        enabled=s.enabled, ride_mode=parse_mode(s.ride_mode),
        trip_rms_mps=cfg.control.trip_rms_mps, ride_ground_mps=s.ride_ground_mps,
        ride_force_ratio=s.ride_force_ratio, quiet_fraction=s.quiet_fraction,
        recover_after_s=s.recover_after_s, settle_s=s.settle_s, excess_ratio=s.excess_ratio,
        growth_per_s=s.growth_per_s, floor_memory_s=s.floor_memory_s, hold_s=s.hold_s,
        backoff=s.backoff, max_attempts=s.max_attempts,
        attempts_window_s=s.attempts_window_s)


class LazyGains(Mapping[Mode, Array]):
    """``floor_gain(cfg, mode)`` per mode, computed on first access (1, shape (N, dof))."""

    def __init__(self, cfg: SystemConfig) -> None:
        self.cfg = cfg
        self._got: dict[Mode, Array] = {}

    def __getitem__(self, mode: Mode) -> Array:
        if mode not in self._got:
            self._got[mode] = floor_gain(self.cfg, mode)
        return self._got[mode]

    def __iter__(self) -> Iterator[Mode]:
        return iter(ALL_MODES)

    def __len__(self) -> int:
        return len(ALL_MODES)


def stability_verdict(cfg: SystemConfig, allow_unstable: bool = False
                      ) -> Callable[[Mode], bool]:
    """``stable(mode)``: the model's verdict, cached per mode; always True with
    ``allow_unstable`` (the user overrode the guard, as ``allow_unstable`` does for a
    switch)."""
    cache: dict[Mode, bool] = {}

    def stable(mode: Mode) -> bool:
        if allow_unstable:
            return True
        if mode not in cache:
            cache[mode] = unstable_reason(cfg, mode) is None
        return cache[mode]
    return stable


def make_supervisor(cfg: SystemConfig, mode: Mode, allow_unstable: bool = False) -> Supervisor:
    """The supervisor of ``cfg`` starting in ``mode`` (with ``supervisor.enabled`` false it
    latches Passive on the first trip, the behaviour without one)."""
    return Supervisor(settings_from(cfg), mode, band_gain=LazyGains(cfg),
                      stable=stability_verdict(cfg, allow_unstable))


__all__ = ["LazyGains", "make_supervisor", "settings_from", "stability_verdict"]
