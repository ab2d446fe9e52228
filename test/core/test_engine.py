"""Batch engine: closed-loop simulation against the analytic model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from dcsms_ros.core.analytics import eq4_tf, freq_response, transmissibility
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import ALL_MODES, Mode

CONFIG = Path(__file__).resolve().parents[2] / "config" / "table1.yaml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(CONFIG)


def _h1(x, y, fs, seg_s=8.0):
    nper = int(fs * seg_s)
    f, pxy = signal.csd(x, y, fs=fs, nperseg=nper)
    _, pxx = signal.welch(x, fs=fs, nperseg=nper)
    _, coh = signal.coherence(x, y, fs=fs, nperseg=nper)
    return f, pxy / pxx, coh


@pytest.fixture(scope="module")
def passive_run(cfg):
    # Table forces off: they are uncorrelated with the ground and would only lower coherence.
    quiet = with_overrides(cfg, {"disturbance.force_rms_n": 0.0})
    return simulate(quiet, Mode.PASSIVE, duration_s=120.0, seed=3)


def test_passive_transmissibility_matches_eq4(cfg, passive_run):
    """Welch H1 of the batch Passive run matches Eq. 4 within 1 dB over 1-30 Hz (coh > 0.9)."""
    res = passive_run
    fs = cfg.plant.rate_hz
    f, h, coh = _h1(res.truth[:, 0, 0], res.truth[:, 2, 0], fs)
    s1, s2 = cfg.plant.stages
    ref = freq_response(eq4_tf(s1.mass, s2.mass, s1.damping, s2.damping, s1.stiffness,
                               s2.stiffness), f)
    band = (f >= 1.0) & (f <= 30.0) & (coh > 0.9)
    assert band.sum() > 100
    err_db = 20 * np.log10(np.abs(h[band]) / np.abs(ref[band]))
    assert np.max(np.abs(err_db)) < 1.0


def test_decoupled_velocities_follow_truth(cfg, passive_run):
    """Geophones plus the extension filter recover the stage-2 velocity above 1 Hz within 1 dB."""
    res = passive_run
    fs = cfg.plant.rate_hz
    f, h, coh = _h1(res.truth[:, 2, 0], res.velocity[:, 2, 0], fs)
    band = (f >= 1.0) & (f <= 30.0) & (coh > 0.9)
    assert band.sum() > 100
    assert np.max(np.abs(20 * np.log10(np.abs(h[band])))) < 1.0


def test_same_seed_same_trajectory(cfg):
    """Two runs with one seed are identical; another seed differs."""
    a = simulate(cfg, Mode.DFBC_FFC, duration_s=0.5, seed=11)
    b = simulate(cfg, Mode.DFBC_FFC, duration_s=0.5, seed=11)
    c = simulate(cfg, Mode.DFBC_FFC, duration_s=0.5, seed=12)
    np.testing.assert_array_equal(a.truth, b.truth)
    np.testing.assert_array_equal(a.applied, b.applied)
    assert not np.array_equal(a.truth, c.truth)


@pytest.mark.parametrize("mode", [Mode.FBC, Mode.DFBC, Mode.DFBC_FFC])
def test_active_transmissibility_matches_analytic(cfg, mode):
    """The closed loop's ground->stage-2 H1 matches the analytic active model within 1.5 dB."""
    quiet = with_overrides(cfg, {"disturbance.force_rms_n": 0.0, "sensors.noise_asd": 0.0,
                                 "sensors.dynamics": False})
    res = simulate(quiet, mode, duration_s=24.0, seed=5)
    fs = cfg.plant.rate_hz
    # Active damping widens the peaks, so 2 s segments resolve them.
    f, h, coh = _h1(res.truth[:, 0, 0], res.truth[:, 2, 0], fs, seg_s=2.0)
    ref = freq_response(transmissibility(quiet, mode)[1], f)
    band = (f >= 1.0) & (f <= 30.0) & (coh > 0.9)
    assert band.sum() > 40
    err_db = 20 * np.log10(np.abs(h[band]) / np.abs(ref[band]))
    assert np.max(np.abs(err_db)) < 1.5


def test_forces_stay_within_limits(cfg):
    """Every applied actuator force stays within its lumped limit in every mode."""
    limit = cfg.plant.stages[0].actuator_count * cfg.actuators.force_limit_n
    for mode in ALL_MODES:
        res = simulate(cfg, mode, duration_s=1.0, seed=2)
        assert np.all(np.isfinite(res.applied))
        assert np.max(np.abs(res.applied)) <= limit


def test_schedule_switches_mode_with_fade(cfg):
    """A scheduled switch is logged and the stage-1 force fades in rather than stepping."""
    res = simulate(cfg, Mode.PASSIVE, duration_s=1.5, seed=4, schedule=[(0.5, Mode.FBC)])
    assert res.mode == [(0, "Passive"), (1000, "FBC")]
    w = res.wrench["fb_stage1"][:, 0]
    assert np.all(w[:1000] == 0.0)
    # 0.5 s fade: after 10 samples the gain is 1 %, so the force is still small.
    assert abs(w[1010]) < 0.05 * np.max(np.abs(w[1000:]))
