"""Batch engine fast path (numba) against the object path that the nodes step."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from dcsms_ros.core import fastsim
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode

pytestmark = pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")

CONFIG = Path(__file__).resolve().parents[2] / "config"
SCHEDULE = ((0.3, Mode.PASSIVE), (0.6, Mode.FBC), (0.9, Mode.DFBC_FFC), (1.1, Mode.FFC))

CASES = {
    "dfbc_ffc": ("table1.yaml", {}, Mode.DFBC_FFC, (), 1.5),
    "schedule_fades": ("table1.yaml", {"control.fade_time_s": 0.2}, Mode.PASSIVE, SCHEDULE,
                       1.5),
    "instant_switch": ("table1.yaml", {"control.fade_time_s": 0.0}, Mode.DFBC, SCHEDULE, 1.5),
    "saturating": ("table1.yaml", {"actuators.force_limit_n": 0.03}, Mode.DFBC_FFC, SCHEDULE,
                   1.5),
    "no_noise": ("table1.yaml", {"sensors.noise_asd": 0.0}, Mode.FBC, (), 0.5),
    "sixdof": ("tem_three_point.yaml", {}, Mode.DFBC_FFC, SCHEDULE, 1.2),
    "sixdof_saturating": ("tem_three_point.yaml", {"actuators.force_limit_n": 0.01},
                          Mode.DFBC_FFC, SCHEDULE, 1.2),
    # fb_stage2 x50 is unstable: the trip latches Passive inside a fast block, which is rerun
    "tripping": ("table1.yaml", {"feedback.stage2.gain": [0.0, 0.0, 2.25e6, 0.0, 0.0, 0.0],
                                 "supervisor.enabled": False},
                 Mode.PASSIVE, ((0.2, Mode.DFBC), (1.0, Mode.FBC)), 1.5),
    # the same under the supervisor: it trips, holds Passive, re-engages DFBC (allowed), trips
    # again, ...; its segments end at the checkpoints instead
    "supervised": ("table1.yaml", {"feedback.stage2.gain": [0.0, 0.0, 2.25e6, 0.0, 0.0, 0.0],
                                   "supervisor.hold_s": 0.3, "supervisor.settle_s": 0.1},
                   Mode.PASSIVE, ((0.2, Mode.DFBC),), 4.0),
}


def _pair(name: str, **kw: object) -> tuple:
    file, over, mode, sched, dur = CASES[name]
    cfg = with_overrides(load_config(CONFIG / file), over)
    kw.setdefault("allow_unstable", True)
    fast = simulate(cfg, mode, dur, seed=11, schedule=sched, fast=True, **kw)
    slow = simulate(cfg, mode, dur, seed=11, schedule=sched, fast=False, **kw)
    return fast, slow


def _series(res: object) -> dict[str, np.ndarray]:
    out = {n: getattr(res, n) for n in ("t", "truth", "raw", "velocity", "applied")}
    out.update({f"wrench/{c}": w for c, w in res.wrench.items()})  # type: ignore[attr-defined]
    return out


@pytest.mark.parametrize("name", sorted(CASES))
def test_fast_matches_object_path(name):
    """Every series, counter and mode entry of the fast path equals the object path (rtol 1e-9)."""
    fast, slow = _pair(name)
    a, b = _series(fast), _series(slow)
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_allclose(a[key], b[key], rtol=1e-9, atol=0.0, err_msg=key)
    assert fast.counters == slow.counters
    assert fast.mode == slow.mode
    assert fast.trip == slow.trip and fast.refused == slow.refused
    assert fast.supervision == slow.supervision
    assert fast.channel_names == slow.channel_names
    assert fast.actuator_names == slow.actuator_names


@pytest.mark.slow
def test_trip_latches_passive_at_a_checkpoint_and_refuses_switches():
    """The unstable gain trips at a checkpoint; Passive from the next sample; the later switch
    to FBC is refused, as the mode-switch node refuses it; a stable run never trips."""
    from dcsms_ros.core.trip import check_samples

    fast, slow = _pair("tripping")
    for key, v in _series(fast).items():
        assert np.array_equal(v, _series(slow)[key]), key
    assert fast.trip is not None and fast.trip.stage in (1, 2)
    every = check_samples(fast.cfg.plant.rate_hz)
    assert (fast.trip.sample + 1) % every == 0
    assert fast.mode == [(0, "Passive"), (400, "DFBC"), (fast.trip.sample + 1, "Passive")]
    assert fast.refused == [(2000, "FBC")]
    assert "above 0.001 m/s" in fast.trip.reason
    calm, _ = _pair("dfbc_ffc")
    assert calm.trip is None


@pytest.mark.parametrize("name", ["saturating", "sixdof_saturating"])
def test_fast_path_is_bit_identical_and_saturates(name):
    """The saturating runs clip and are bit for bit the object path's (same BLAS gemv calls)."""
    fast, slow = _pair(name)
    assert slow.counters["saturations"] > 0
    for key, v in _series(fast).items():
        assert np.array_equal(v, _series(slow)[key]), key


def test_fast_ground_replay_loops_and_warns():
    """A replayed ground record loops with one warning, on both paths alike."""
    cfg = load_config(CONFIG / "table1.yaml")
    rec = 1e-6 * np.sin(np.arange(700) * 0.05)[:, None]
    runs = []
    for fast in (True, False):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            runs.append(simulate(cfg, Mode.DFBC_FFC, 1.0, seed=2, ground=rec, fast=fast))
        assert sum("ground replay ended" in str(w.message) for w in caught) == 1
    for key, v in _series(runs[0]).items():
        np.testing.assert_allclose(v, _series(runs[1])[key], rtol=1e-9, atol=0.0, err_msg=key)


def test_fast_progress_calls_match():
    """The fast path reports progress at the same fractions as the object path."""
    cfg = load_config(CONFIG / "table1.yaml")
    calls: dict[bool, list[float]] = {True: [], False: []}
    for fast in (True, False):
        simulate(cfg, Mode.FBC, 0.3, seed=1, fast=fast, progress=calls[fast].append)
    assert calls[True] == calls[False]
    assert len(calls[True]) == 100


def test_fast_falls_back_on_nonfinite():
    """A run that overflows is redone on the object path, fault counters included."""
    cfg = load_config(CONFIG / "table1.yaml")
    rec = np.full((100, 1), 1e308)
    rec[::2] *= -1.0
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        runs = [simulate(cfg, Mode.FBC, 0.05, seed=1, ground=rec, fast=fast)
                for fast in (True, False)]
    assert runs[1].counters["nonfinite_inputs"] > 0
    assert runs[0].counters == runs[1].counters
    np.testing.assert_array_equal(runs[0].raw, runs[1].raw)
