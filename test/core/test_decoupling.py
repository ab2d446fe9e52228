"""Decoupler: LF extension, pinv(S) per body, non-finite handling."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.testing import assert_allclose
from sixdof_helper import sixdof_config

from dcsms_ros.core.config import load_config
from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.core.sensors import GeophoneArray, channel_layout, channel_matrix

FS = 2000.0


def test_channel_names_follow_layout():
    """channel_names is the sensor layout order."""
    cfg = sixdof_config()
    assert Decoupler(cfg).channel_names == [c.name for c in channel_layout(cfg)]


def test_rigid_motion_round_trip_ideal_sensors():
    """Known rigid twists -> channel matrix -> Decoupler returns the twists exactly (6dof)."""
    cfg = sixdof_config(**{"sensors.dynamics": False})
    dec = Decoupler(cfg)
    m = channel_matrix(cfg)
    rng = np.random.default_rng(11)
    for _ in range(5):
        twists = rng.standard_normal((3, 6))
        assert_allclose(dec.step(m @ twists.ravel()), twists, rtol=1e-10, atol=1e-12)


def test_rigid_sinusoid_through_geophones_gets_extended_response():
    """A 6dof rigid sinusoid through geophones + Decoupler equals twist * extended response."""
    cfg = sixdof_config(**{"sensors.noise_asd": 0.0})
    f0, n = 20.0, 6000
    t = np.arange(n) / FS
    amp = np.random.default_rng(5).standard_normal((3, 6))
    m = channel_matrix(cfg)
    geo, dec = GeophoneArray(cfg, np.random.default_rng(0)), Decoupler(cfg)
    out = np.array([dec.step(geo.step(m @ (amp.ravel() * math.sin(2 * math.pi * f0 * tk))))
                    for tk in t])
    sc = cfg.sensors
    we, s = 2 * math.pi * sc.extension_hz, 2j * math.pi * f0
    h = s**2 / (s**2 + 2 * sc.extension_damping * we * s + we**2)
    # least-squares fit of the last second: y = a sin + b cos -> complex gain a + j b
    tail = slice(n - 2000, n)
    ph = 2 * math.pi * f0 * t[tail]
    basis = np.column_stack([np.sin(ph), np.cos(ph)])
    coef, *_ = np.linalg.lstsq(basis, out[tail].reshape(2000, -1), rcond=None)
    gain = (coef[0] + 1j * coef[1]).reshape(3, 6)
    assert_allclose(gain, amp * h, rtol=2e-3, atol=2e-3 * np.max(np.abs(amp)))


def test_nonfinite_channel_zeroes_its_body_only():
    """A NaN channel zeroes its body's twist, is counted, and never poisons later samples."""
    cfg = load_config()
    dec = Decoupler(cfg)
    ref = Decoupler(cfg)
    x = np.random.default_rng(9).standard_normal((50, 3))
    for k in range(50):
        raw = x[k].copy()
        if k in (10, 11):
            raw[1] = np.nan if k == 10 else np.inf
        y = dec.step(raw)
        y_ref = ref.step(x[k] if k not in (10, 11) else np.where([1, 0, 1], x[k], 0.0))
        assert np.isfinite(y).all()
        if k in (10, 11):
            assert y[1, 0] == 0.0
            assert_allclose(y[[0, 2]], y_ref[[0, 2]], rtol=0, atol=0)
    assert dec.nonfinite == 2
    assert dec.step(np.zeros(3)).shape == (3, 1)


def test_extension_disabled_for_ideal_1dof():
    """1dof with ideal sensors: the Decoupler is the identity."""
    cfg = load_config()
    cfg = replace(cfg, sensors=replace(cfg.sensors, dynamics=False))
    dec = Decoupler(cfg)
    assert_allclose(dec.step([1.0, 2.0, 3.0]), [[1.0], [2.0], [3.0]])
