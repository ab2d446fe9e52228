"""Geophone model, LF extension, channel layout and the discrete geophone array."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal
from sixdof_helper import sixdof_config

from dcsms_ros.core.config import SensorConfig, load_config
from dcsms_ros.core.filterdesign import Rational
from dcsms_ros.core.filters import to_sos
from dcsms_ros.core.geometry import skew
from dcsms_ros.core.sensors import (
    GeophoneArray,
    channel_layout,
    channel_matrix,
    extension_tf,
    geophone_tf,
)

FS = 2000.0


def cresp(tf, f_hz):
    s = 2j * np.pi * np.asarray(f_hz, float)
    return np.polyval(tf.num, s) / np.polyval(tf.den, s)


@pytest.mark.parametrize(("fn", "zeta"), [(4.5, 0.42), (1.0, 0.7), (10.0, 0.2)])
def test_geophone_resonance_and_passband(fn, zeta):
    """|H| is 1/(2 zeta) at the natural frequency, -> 1 far above it, ~ (f/fn)^2 far below."""
    tf = geophone_tf(SensorConfig(natural_frequency_hz=fn, damping_ratio=zeta))
    assert_allclose(abs(cresp(tf, fn)), 1 / (2 * zeta), rtol=1e-9)
    assert_allclose(abs(cresp(tf, 1e4 * fn)), 1.0, rtol=1e-6)
    assert_allclose(abs(cresp(tf, 1e-4 * fn)), 1e-8, rtol=1e-6)


@pytest.mark.parametrize(("fe", "ze"), [(0.5, 0.707), (1.0, 0.5)])
def test_geophone_times_extension_is_extended_response(fe, ze):
    """geophone * extension == s^2 / (s^2 + 2 ze we s + we^2), continuous and discrete."""
    sc = SensorConfig(extension_hz=fe, extension_damping=ze)
    we = 2 * math.pi * fe
    f = np.geomspace(0.05, 200, 50)
    s = 2j * np.pi * f
    ideal = s**2 / (s**2 + 2 * ze * we * s + we**2)
    assert_allclose(cresp(geophone_tf(sc), f) * cresp(extension_tf(sc), f), ideal, rtol=1e-9)
    x = np.random.default_rng(1).standard_normal(4000)
    cascade = signal.sosfilt(to_sos(extension_tf(sc), FS), signal.sosfilt(
        to_sos(geophone_tf(sc), FS), x))
    direct = signal.sosfilt(to_sos(Rational.of([1, 0, 0], [1, 2 * ze * we, we**2]), FS), x)
    assert_allclose(cascade, direct, rtol=1e-7, atol=1e-9 * np.max(np.abs(direct)))


@pytest.mark.parametrize("sc", [SensorConfig(dynamics=False), SensorConfig(extension_hz=0.0)])
def test_identity_cases(sc):
    """Ideal sensors have no dynamics; extension_hz = 0 disables the extension."""
    f = np.array([0.1, 3.0, 50.0])
    assert_allclose(cresp(extension_tf(sc), f), 1.0)
    if not sc.dynamics:
        assert_allclose(cresp(geophone_tf(sc), f), 1.0)


def test_layout_1dof():
    """1dof: one vertical channel per body, names <body>/z, identity channel matrix."""
    cfg = load_config()
    assert [c.name for c in channel_layout(cfg)] == ["ground/z", "stage1/z", "stage2/z"]
    assert_allclose(channel_matrix(cfg), np.eye(3))


def test_layout_and_channel_matrix_6dof():
    """6dof: channels ground, stage1, stage2; each row is d . (v + w x (r - ref))."""
    cfg = sixdof_config()
    layout = channel_layout(cfg)
    assert [c.name for c in layout[:2]] == ["ground/g1", "ground/g2"]
    assert [c.body for c in layout] == ["ground"] * 6 + ["stage1"] * 6 + ["stage2"] * 6
    twists = np.random.default_rng(2).standard_normal((3, 6))
    refs = [np.zeros(3)] + [np.array(st.com) for st in cfg.plant.stages]
    body = {"ground": 0, "stage1": 1, "stage2": 2}
    expected = []
    for c in layout:
        i = body[c.body]
        v, w = twists[i, :3], twists[i, 3:]
        expected.append(np.dot(c.direction, v + skew(w) @ (np.array(c.position) - refs[i])))
    assert_allclose(channel_matrix(cfg) @ twists.ravel(), expected, rtol=1e-12, atol=1e-14)


def test_array_noise_level_and_determinism():
    """Self-noise std = asd*sqrt(fs/2) per channel; the same seed gives the same readings."""
    cfg = load_config()
    cfg = replace(cfg, sensors=replace(cfg.sensors, noise_asd=1e-8))
    runs = []
    for _ in range(2):
        g = GeophoneArray(cfg, np.random.default_rng(7))
        runs.append(np.array([g.step(np.zeros(3)) for _ in range(20000)]))
    assert_allclose(runs[0], runs[1], rtol=0, atol=0)
    assert_allclose(runs[0].std(axis=0), 1e-8 * math.sqrt(FS / 2), rtol=0.03)


def test_array_response_matches_geophone():
    """Without noise the array filters each channel by the discrete geophone."""
    cfg = load_config()
    cfg = replace(cfg, sensors=replace(cfg.sensors, noise_asd=0.0))
    g = GeophoneArray(cfg, np.random.default_rng(0))
    x = np.random.default_rng(3).standard_normal((500, 3))
    out = np.array([g.step(row) for row in x])
    ref = signal.sosfilt(to_sos(geophone_tf(cfg.sensors), FS), x, axis=0)
    assert_allclose(out, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))
