"""Filter design, Tustin SOS discretisation and the per-sample SOS filter."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from dcsms_ros.core.config import FeedbackConfig, FeedforwardConfig
from dcsms_ros.core.filterdesign import Rational
from dcsms_ros.core.filters import (
    feedback_sos,
    feedback_tf,
    feedforward_tf,
    highpass,
    leadlag,
    lowpass,
    notch,
    to_sos,
)
from dcsms_ros.core.sosfilter import SosFilter
from dcsms_ros.errors import ConfigError

FS = 2000.0
FB = FeedbackConfig(gain=(1e3, 2e3, 3e4, 0.0, 0.0, 5.0), highpass_hz=0.3, highpass_order=2,
                    lowpass_hz=150.0, lowpass_order=2, notch_hz=60.0, notch_q=5.0,
                    lead_hz=8.0, lag_hz=40.0)
FF = FeedforwardConfig()
C1, K1 = 1960.0, 1.2e6

DESIGNS = {
    "feedback": feedback_tf(FB, 2),
    "feedback_plain": feedback_tf(FeedbackConfig(gain=(0, 0, 3e4, 0, 0, 0)), 2),
    "feedforward": feedforward_tf(FF, C1, K1),
    "highpass3": highpass(3, 0.5),
    "lowpass4": lowpass(4, 150.0),
    "notch": notch(40.0, 3.0),
    "leadlag": leadlag(5.0, 50.0),
}


def cresp(tf, f_hz):
    s = 2j * np.pi * np.asarray(f_hz, float)
    return np.polyval(tf.num, s) / np.polyval(tf.den, s)


@pytest.mark.parametrize("name", sorted(DESIGNS))
def test_sos_step_equals_sosfilt(name):
    """SosFilter.step reproduces scipy.signal.sosfilt sample by sample on random input."""
    sos = to_sos(DESIGNS[name], FS)
    x = np.random.default_rng(3).standard_normal((600, 3))
    ref = signal.sosfilt(sos, x, axis=0)
    f = SosFilter(sos, 3)
    out = np.array([f.step(row) for row in x])
    assert_allclose(out, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))


def test_sos_per_channel_coefficients():
    """A (channels, n, 6) SOS array filters each channel with its own sections."""
    sa, sb = to_sos(DESIGNS["feedback"], FS), to_sos(2.0 * DESIGNS["feedback"], FS)
    x = np.random.default_rng(4).standard_normal((300, 2))
    f = SosFilter(np.stack([sa, sb]), 2)
    out = f.run(x)
    assert_allclose(out[:, 0], signal.sosfilt(sa, x[:, 0]), rtol=1e-12, atol=1e-9)
    assert_allclose(out[:, 1], signal.sosfilt(sb, x[:, 1]), rtol=1e-12, atol=1e-9)


def test_state_copy_restores_output():
    """set_state(get_state()) replays the same samples exactly."""
    f = SosFilter(to_sos(DESIGNS["feedforward"], FS), 2)
    x = np.random.default_rng(5).standard_normal((200, 2))
    f.run(x[:100])
    saved = f.get_state()
    a = f.run(x[100:])
    f.set_state(saved)
    assert_allclose(f.run(x[100:]), a, rtol=0, atol=0)
    f.reset()
    assert not f.get_state().any()


@pytest.mark.parametrize("name", sorted(DESIGNS))
def test_discrete_matches_continuous(name):
    """Tustin SOS (notch prewarped) at 2 kHz matches the design within 0.1 dB over 1-100 Hz."""
    tf = DESIGNS[name]
    f = np.geomspace(1.0, 100.0, 200)
    sos = (feedback_sos(FB, 2, FS) if name == "feedback"
           else to_sos(tf, FS, 40.0 if name == "notch" else 0.0))
    _, hd = signal.sosfreqz(sos, worN=f, fs=FS)
    hc = cresp(tf, f)
    ok = np.abs(hc) > 1e-3 * np.max(np.abs(hc))  # skip the notch floor, where dB is undefined
    assert_allclose(20 * np.log10(np.abs(hd[ok])), 20 * np.log10(np.abs(hc[ok])), atol=0.1)


@pytest.mark.parametrize(("tf", "f_hz", "expected"), [
    (highpass(1, 2.0), 2.0, 1 / math.sqrt(2)),
    (highpass(3, 2.0), 2.0, 1 / math.sqrt(2)),
    (lowpass(2, 50.0), 50.0, 1 / math.sqrt(2)),
    (lowpass(4, 50.0), 500.0, 1 / math.sqrt(1 + 10.0 ** 8)),
    (notch(40.0, 3.0), 40.0, 0.0),
    (notch(40.0, 3.0), 40.0 * (math.sqrt(1 + 1 / 36) + 1 / 6), 1 / math.sqrt(2)),
    (leadlag(5.0, 50.0), 1e-6, 1.0),
    (leadlag(5.0, 50.0), 1e6, 10.0),
    (highpass(2, 0.0) * lowpass(2, 0.0) * notch(0.0, 5.0) * leadlag(0.0, 0.0), 7.0, 1.0),
])
def test_design_magnitudes(tf, f_hz, expected):
    """Corner, notch and lead-lag magnitudes equal their analytic values; corner 0 -> 1."""
    assert_allclose(abs(cresp(tf, f_hz)), expected, rtol=1e-6, atol=1e-12)


def test_feedback_gain_and_structure():
    """feedback_tf is gain[axis] times the product of its stages."""
    ref = 3e4 * highpass(2, 0.3) * lowpass(2, 150.0) * notch(60.0, 5.0) * leadlag(8.0, 40.0)
    f = np.geomspace(0.1, 500, 30)
    assert_allclose(cresp(feedback_tf(FB, 2), f), cresp(ref, f), rtol=1e-9)
    assert_allclose(cresp(feedback_tf(FB, 3), f), 0.0)


def test_leadlag_without_pole_rejected():
    """A lead zero without a lag pole is a configuration error (improper stage)."""
    with pytest.raises(ConfigError, match="lag_hz"):
        leadlag(5.0, 0.0)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_feedforward_asymptote_and_no_pole_at_zero(order):
    """feedforward_tf -> gain*(c1 + k1/s) within 1 % well above the HP corner; no pole at 0."""
    ff = FeedforwardConfig(gain=0.8, highpass_hz=0.02, highpass_order=order, lowpass_hz=0.0)
    tf = feedforward_tf(ff, C1, K1)
    f = np.geomspace(10.0, 100.0, 12)
    ideal = 0.8 * (C1 + K1 / (2j * np.pi * f))
    assert_allclose(cresp(tf, f), ideal, rtol=0.01)
    poles = np.roots(tf.den)
    assert np.min(np.abs(poles)) > 0.1 and np.all(poles.real < 0)
    assert np.isfinite(cresp(tf, 0.0))


def test_feedforward_needs_highpass():
    """Without a high-pass corner the integrator cannot be cancelled."""
    with pytest.raises(ConfigError):
        feedforward_tf(FeedforwardConfig(highpass_hz=0.0), C1, K1)


def test_to_sos_static_zero_and_improper():
    """A static gain gives one section, zero gives zero output, improper TFs raise."""
    assert_allclose(to_sos(Rational.of([2.5], [1.0]), FS), [[2.5, 0, 0, 1, 0, 0]])
    assert_allclose(to_sos(Rational.of([0.0], [1.0, 1.0]), FS)[:, :3], 0.0)
    with pytest.raises(ValueError, match="improper"):
        to_sos(Rational.of([1.0, 0.0, 0.0], [1.0, 1.0]), FS)
