"""The supervisor in the batch engine (object path), issue 22's scenarios on the real loop:
table1 DFBC+FFC under the preset's floor with a burst 3000x stronger from 40 to 55 s, and the
TEM fixture's DFBC that the model calls unstable, run anyway (allow_unstable)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcsms_ros.core.check import unstable_reason
from dcsms_ros.core.config import SystemConfig, load_config
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
    plain = simulate(cfg, Mode.DFBC_FFC, duration, ground=ground)
    assert plain.trip is not None and 40.0 < plain.trip.sample * cfg.plant.dt < 42.0
    sup = _supervisor(cfg, Mode.DFBC_FFC)
    res = Simulation(cfg, Mode.DFBC_FFC, ground=ground, supervisor=sup).run(
        int(duration * cfg.plant.rate_hz))
    assert res is not None
    states = [tr.state for tr in sup.transitions]
    assert State.TRIPPED not in states and State.LATCHED not in states, sup.transitions
    assert State.RIDE_THROUGH in states, sup.transitions
    k_back, label = res.mode[-1]
    assert label == Mode.DFBC_FFC.label, res.mode
    assert k_back * cfg.plant.dt - 55.0 <= 20.0, res.mode
    assert sup.state is State.ENGAGED


@pytest.mark.slow
def test_unstable_loop_is_retried_then_latched() -> None:
    """tem_unstable DFBC, allowed: TRIPPED, re-engaged at most 3 times, then LATCHED with the
    reason; Passive to the end."""
    cfg = load_config(UNSTABLE)
    sup = _supervisor(cfg, Mode.DFBC, allow=True)
    res = Simulation(cfg, Mode.DFBC, supervisor=sup).run(int(190.0 * cfg.plant.rate_hz))
    assert res is not None
    states = [tr.state for tr in sup.transitions]
    assert states.count(State.RECOVERING) <= 3, sup.transitions
    assert states[-1] is State.LATCHED and res.mode[-1][1] == Mode.PASSIVE.label, sup.transitions
    assert "gave up" in sup.reason, sup.reason
