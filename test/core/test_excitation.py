"""Actuator excitation: specifications, signals, the batch engine (both paths) and the loop
model's ``excite`` input against the engine."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from dcsms_ros.core import fastsim
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.disturbance import BandNoise
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.excitation import (
    Excitation,
    check_specs,
    excitation_signal,
    parse_spec,
)
from dcsms_ros.core.loop_model import loop_model
from dcsms_ros.core.modes import Mode
from dcsms_ros.errors import ConfigError

CONFIG = Path(__file__).resolve().parents[2] / "config"
FS = 2000.0


@pytest.fixture(scope="module")
def table1():
    return load_config(CONFIG / "table1.yaml")


@pytest.mark.parametrize("text, expect", [
    ("stage1.z:white:5", ("stage1", "z", "white", 5.0, (0.5, 100.0))),
    ("stage2.x:sweep:20:0.5-50", ("stage2", "x", "sweep", 20.0, (0.5, 50.0))),
    ("stage1.z:sweep:3:1-80:10", ("stage1", "z", "sweep", 3.0, (1.0, 80.0))),
    (" stage1.rz : stepped : 2 : 1-30 : 7 ", ("stage1", "rz", "stepped", 2.0, (1.0, 30.0))),
    ("stage1.z:white:5@10-40", ("stage1", "z", "white", 5.0, (0.5, 100.0))),
])
def test_parse_spec(text, expect):
    s = parse_spec(text)
    assert (s.stage_name, s.axis, s.kind, s.amplitude, s.band_hz) == expect
    assert parse_spec(s.text) == s  # the canonical text parses back to the same spec


@pytest.mark.parametrize("text, match", [
    ("stage1.z", "expected STAGE.AXIS"),
    ("stage1.q:white:5", "unknown axis"),
    ("stage1.z:pink:5", "unknown kind"),
    ("stage1.z:white:-1", "must be > 0"),
    ("stage1.z:white:abc", "not a number"),
    ("stage1.z:white:5:50-1", "0 < LO < HI"),
    ("stage1.z:white:5:1-50:3", "no third field"),
    ("stage1.z:stepped:5:1-50:x", "integer"),
    ("stage1.z:sweep:5:1-50:0", "period must be > 0"),
    ("stage1.z:white:5@10", "expected @T0-T1"),
    ("stage1.z:white:5@10-5", "0 <= T0 < T1"),
])
def test_parse_spec_refuses(text, match):
    with pytest.raises(ConfigError, match=match):
        parse_spec(text)


@pytest.mark.parametrize("texts, match", [
    (["stage1.z:white:5", "stage2.z:white:5"], "one stage"),
    (["stage3.z:white:5"], "does not exist"),
    (["stage1.x:white:5"], "only z"),
    (["stage1.z:white:101"], "exceeds the actuator limit"),  # 4 x 101 N > 4 x 100 N
    (["stage1.z:sweep:401"], "exceeds the actuator limit"),
    (["stage1.z:white:5:1-1500"], "Nyquist"),
])
def test_check_specs_refuses(table1, texts, match):
    with pytest.raises(ConfigError, match=match):
        check_specs(table1, [parse_spec(t) for t in texts])


def test_white_noise_rms_band_and_clip(table1):
    """5 N RMS band-limited white noise: RMS within 2 %, its PSD that of the band filter (the
    disturbances' second-order Butterworth edges), peak at most 4 sigma; per-sample and block
    draws give the same values."""
    spec = [parse_spec("stage1.z:white:5:2-50")]
    x = excitation_signal(table1, spec, 200_000, seed=4)
    assert x.shape == (200_000, 2, 1)
    assert np.all(x[:, 1] == 0.0)
    v = x[:, 0, 0]
    assert np.sqrt(np.mean(v ** 2)) == pytest.approx(5.0, rel=0.02)
    assert np.max(np.abs(v)) <= 20.0
    f, p = signal.welch(v, FS, nperseg=8192)
    noise = BandNoise(5.0, (2.0, 50.0), FS, 1, np.random.default_rng(0))
    _, h = signal.sosfreqz(noise.sos, worN=f, fs=FS)
    expect = 2.0 / FS * (noise.scale[0] * np.abs(h)) ** 2
    inside = (f >= 1) & (f <= 100)
    np.testing.assert_allclose(np.mean(p[inside] / expect[inside]), 1.0, rtol=0.03)
    one = Excitation(table1, spec, seed=4, duration_s=1.0)
    per_sample = np.array([one.next() for _ in range(300)])
    np.testing.assert_array_equal(per_sample, x[:300])


def test_sweep_and_stepped_frequencies(table1):
    """A log sweep's instantaneous frequency runs LO -> HI over the period; a stepped sine holds
    each of its log-spaced frequencies for period / N."""
    sweep = excitation_signal(table1, [parse_spec("stage2.z:sweep:20:1-40")], 40_000, 1)[:, 1, 0]
    assert np.max(np.abs(sweep)) == pytest.approx(20.0, rel=1e-3)
    # cycles (upward zero crossings) between t1 and t2 against the log-sweep phase law
    up = np.flatnonzero((sweep[:-1] < 0) & (sweep[1:] >= 0)) / FS

    def cycles(t):  # phase / 2 pi of a 1 -> 40 Hz log sweep over 20 s
        return 1.0 * 20.0 / np.log(40.0) * (40.0 ** (t / 20.0) - 1.0)

    for t1, t2 in ((2.0, 10.0), (10.0, 15.0), (15.0, 19.0)):
        n = np.count_nonzero((up >= t1) & (up < t2))
        assert abs(n - (cycles(t2) - cycles(t1))) <= 1.0
    stepped = excitation_signal(table1, [parse_spec("stage1.z:stepped:3:2-32:5")], 50_000,
                                1)[:, 0, 0]
    for i, f0 in enumerate(np.geomspace(2, 32, 5)):
        seg = stepped[i * 10_000:(i + 1) * 10_000]
        f, p = signal.periodogram(seg, FS)
        assert f[np.argmax(p)] == pytest.approx(f0, abs=0.25)


def test_window_keeps_the_excitation_on_from_t0_to_t1(table1):
    """@T0-T1: zero outside, the same white noise inside as without a window; a windowed sweep
    starts at T0 and sweeps over T1 - T0."""
    full = excitation_signal(table1, [parse_spec("stage1.z:white:5")], 8000, 2)
    win = excitation_signal(table1, [parse_spec("stage1.z:white:5@1-3")], 8000, 2)
    np.testing.assert_array_equal(win[2000:6000], full[2000:6000])
    assert not win[:2000].any() and not win[6000:].any()
    sweep = excitation_signal(table1, [parse_spec("stage1.z:sweep:4:1-40@1-3")], 8000, 2)
    plain = excitation_signal(table1, [parse_spec("stage1.z:sweep:4:1-40:2")], 4000, 2)
    np.testing.assert_allclose(sweep[2000:6000], plain, atol=1e-12)


def _excite(cfg, text, seconds, seed=5):
    return excitation_signal(cfg, [parse_spec(text)], int(seconds * FS), seed)


CASES = {
    "passive_white": ({}, Mode.PASSIVE, (), "stage1.z:white:5"),
    "dfbc_ffc_sweep": ({}, Mode.DFBC_FFC, ((0.4, Mode.FBC),), "stage2.z:sweep:30:1-80"),
    "saturating": ({"actuators.force_limit_n": 0.5}, Mode.DFBC_FFC, (), "stage1.z:sweep:2:1-20"),
}


@pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")
@pytest.mark.parametrize("name", sorted(CASES))
def test_fast_path_bit_identical_with_excitation(table1, name):
    """The excitation enters both engine paths alike: every series bit for bit."""
    over, mode, sched, text = CASES[name]
    cfg = with_overrides(table1, over)
    exc = _excite(cfg, text, 0.8)
    runs = [simulate(cfg, mode, 1.0, seed=3, schedule=sched, excite=exc, fast=f)
            for f in (True, False)]
    for key in ("truth", "raw", "velocity", "applied", "excitation"):
        assert np.array_equal(getattr(runs[0], key), getattr(runs[1], key)), key
    assert runs[0].counters == runs[1].counters
    if name == "saturating":
        assert runs[0].counters["saturations"] > 0
    # the first 0.8 s carry the excitation, the rest of the run none
    np.testing.assert_array_equal(runs[0].excitation[:1600], exc)
    assert not runs[0].excitation[1600:].any()


@pytest.mark.parametrize("fast", [True, False] if fastsim.available() else [False])
def test_trip_stops_the_excitation(table1, fast):
    """An excitation that trips the instability monitor stops on the sample the controllers go
    off; nothing is added while tripped."""
    cfg = with_overrides(table1, {"control.trip_rms_mps": 2e-6, "supervisor.enabled": False})
    exc = _excite(cfg, "stage1.z:white:20", 2.0)
    res = simulate(cfg, Mode.FBC, 2.0, seed=3, excite=exc, fast=fast)
    assert res.trip is not None
    stop = res.trip.sample + 1
    np.testing.assert_array_equal(res.excitation[:stop], exc[:stop])
    assert not res.excitation[stop:].any()
    assert res.mode[-1] == (stop, "Passive")
    # the supervisor trips on the same checkpoint (a quiet floor: an instability) and the
    # excitation stops there too, for good, though the supervisor later re-engages FBC
    sup = simulate(with_overrides(cfg, {"supervisor.enabled": True}), Mode.FBC, 2.0, seed=3,
                   excite=exc, fast=fast)
    first = sup.supervision[0]
    assert first.state.value == "TRIPPED" and first.sample + 1 == stop
    np.testing.assert_array_equal(sup.excitation[:stop], exc[:stop])
    assert not sup.excitation[stop:].any()


def _quiet(cfg):
    return with_overrides(cfg, {"disturbance.ground_rms_mps": [0.0, 0.0, 0.0],
                                "disturbance.force_rms_n": 0.0, "sensors.noise_asd": 0.0})


@pytest.mark.parametrize("mode, text, plant_over", [
    (Mode.PASSIVE, "stage1.z:white:5", {}),
    (Mode.PASSIVE, "stage2.z:white:5", {"m1": 1100.0, "k2": 1.0e6, "c1": 2900.0}),
    (Mode.DFBC_FFC, "stage1.z:sweep:10:1-60", {"m2": 700.0, "k1": 1.3e6}),
    (Mode.FBC, "stage2.z:white:3", {"sensors.natural_frequency_hz": 4.0,
                                     "sensors.damping_ratio": 0.5}),
])
def test_loop_model_excite_input_equals_the_engine(table1, mode, text, plant_over):
    """Without disturbances the engine's decoupled velocities are the loop model's ``excite``
    -> ``velocity`` response to the same excitation, to rounding; also with a plant (masses,
    suspensions, geophone dynamics) that differs from the controllers' configuration."""
    cfg = _quiet(table1)
    plant = with_overrides(cfg, plant_over) if plant_over else None
    exc = _excite(cfg, text, 1.5)
    res = simulate(cfg, mode, 1.5, seed=1, excite=exc, plant=plant, trip=False)
    m = loop_model(cfg, mode, plant=plant).select("excite", "velocity")
    _, y, _ = signal.dlsim((m.a, m.b, m.c, m.d, m.dt), exc.reshape(exc.shape[0], -1))
    scale = np.max(np.abs(res.velocity))
    assert scale > 1e-7
    np.testing.assert_allclose(res.velocity.reshape(y.shape), y, rtol=0, atol=1e-9 * scale)


def test_plant_may_not_change_structure(table1):
    with pytest.raises(ConfigError, match=r"feedback\.stage1\.gain"):
        simulate(table1, Mode.PASSIVE, 0.01, plant=with_overrides(
            table1, {"feedback.stage1.gain": [0, 0, 1.0, 0, 0, 0]}))
    with pytest.raises(ConfigError, match=r"actuators\.count"):
        loop_model(table1, Mode.PASSIVE, plant=with_overrides(
            table1, {"stage1.actuators.count": 2}))
