"""The supervisor in the batch engine (object path), issue 22's scenarios on the real loop:
table1 DFBC+FFC under the preset's floor with a burst 3000x stronger from 40 to 55 s, and the
TEM fixture's DFBC that the model calls unstable, run anyway (allow_unstable)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcsms_ros.core.check import unstable_reason
from dcsms_ros.core.config import SystemConfig, load_config, with_overrides
from dcsms_ros.core.engine import Simulation, simulate
from dcsms_ros.core.floor import floor_gain
from dcsms_ros.core.modes import ALL_MODES, Mode
from dcsms_ros.core.supervisor import State, Supervisor, SupervisorSettings

UNSTABLE = Path(__file__).resolve().parents[1] / "fixtures" / "tem_unstable.yaml"


def _burst_floor(cfg: SystemConfig, duration_s: float) -> np.ndarray:
    """The preset's own floor (the true ground twist of a run), x3000 from 40 to 55 s."""
    ground = simulate(cfg, Mode.PASSIVE, duration_s + 1.0, trip=False).truth[:, 0].copy()
    fs = cfg.plant.rate_hz
    ground[int(40.0 * fs):int(55.0 * fs)] *= 3000.0
    return np.asarray(ground)


def _supervisor(cfg: SystemConfig, mode: Mode, allow: bool = False) -> Supervisor:
    return Supervisor(SupervisorSettings(), mode,
                      band_gain={m: floor_gain(cfg, m) for m in ALL_MODES},
                      stable=lambda m: allow or unstable_reason(cfg, m) is None)


@pytest.mark.slow
def test_burst_rides_through_and_dfbc_ffc_comes_back(cfg: SystemConfig) -> None:
    """Without the supervisor the trip latches Passive in the burst (issue 22: 40.9 s); with it
    DFBC+FFC is back <= 20 s after the burst ends and stays; nothing trips or latches."""
    duration = 90.0
    ground = _burst_floor(cfg, duration)
    plain = simulate(with_overrides(cfg, {"supervisor.enabled": False}), Mode.DFBC_FFC,
                     duration, ground=ground)
    assert plain.trip is not None and 40.0 < plain.trip.sample * cfg.plant.dt < 42.0
    res = simulate(cfg, Mode.DFBC_FFC, duration, ground=ground)  # the preset's supervisor
    states = [tr.state for tr in res.supervision]
    assert State.TRIPPED not in states and State.LATCHED not in states, res.supervision
    assert State.RIDE_THROUGH in states, res.supervision
    k_back, label = res.mode[-1]
    assert label == Mode.DFBC_FFC.label, res.mode
    assert k_back * cfg.plant.dt - 55.0 <= 20.0, res.mode
    assert states[-1] is State.ENGAGED
    # the explicit object path with the supervisor built by hand decides the same
    sup = _supervisor(cfg, Mode.DFBC_FFC)
    obj = Simulation(cfg, Mode.DFBC_FFC, ground=ground, supervisor=sup, fast=False).run(
        int(duration * cfg.plant.rate_hz))
    assert obj is not None and obj.supervision == res.supervision


@pytest.mark.slow
def test_unstable_loop_is_retried_then_latched() -> None:
    """tem_unstable DFBC, allowed: TRIPPED, re-engaged at most 3 times, then LATCHED with the
    reason; Passive to the end."""
    cfg = load_config(UNSTABLE)
    res = simulate(cfg, Mode.DFBC, 190.0, allow_unstable=True)
    states = [tr.state for tr in res.supervision]
    assert states.count(State.RECOVERING) <= 3, res.supervision
    assert states[-1] is State.LATCHED and res.mode[-1][1] == Mode.PASSIVE.label, \
        res.supervision
    assert "gave up" in res.supervision[-1].reason, res.supervision[-1]
    # without allow_unstable the supervisor never re-engages the unstable mode: latched at once
    once = simulate(cfg, Mode.DFBC, 150.0)
    assert [tr.state for tr in once.supervision] == [State.TRIPPED, State.LATCHED], \
        once.supervision
