"""The numpy filter designs against scipy.signal (and python-control products): every filter
the presets build, and ranges of orders, corners and band types."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import control as ct  # type: ignore[import-untyped]
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy import signal

from dcsms_ros.core import fastsim
from dcsms_ros.core import filterdesign as fd
from dcsms_ros.core.config import SystemConfig, load_config
from dcsms_ros.core.controllers import suspension_totals
from dcsms_ros.core.disturbance import band_sos
from dcsms_ros.core.filters import feedback_tf, feedforward_tf, to_sos
from dcsms_ros.core.sensors import extension_tf, geophone_tf
from dcsms_ros.core.sosfilter import sosfilt
from dcsms_ros.core.trip import TripMonitor

PRESETS = sorted(Path(__file__).resolve().parents[2].glob("config/*.yaml"))
RTOL = 1e-12


def close(got: np.ndarray, ref: np.ndarray) -> None:
    """Equal to ~1e-12 of the largest coefficient (they agree bit for bit today)."""
    ref = np.asarray(ref)
    assert got.shape == ref.shape
    if ref.size:
        assert_allclose(got, ref, rtol=RTOL, atol=RTOL * float(np.max(np.abs(ref))))


# -- the reference: python-control products of scipy's analog designs, scipy's Tustin SOS --

def _ref_butter(order: int, hz: float, btype: str) -> ct.TransferFunction:
    if hz <= 0.0:
        return ct.tf([1.0], [1.0])
    return ct.tf(*signal.butter(order, 2.0 * math.pi * hz, btype=btype, analog=True))


def _ref_feedback(cfg: SystemConfig, stage: int, axis: int) -> ct.TransferFunction:
    fb = cfg.feedback[stage]
    w = 2.0 * math.pi * fb.notch_hz
    notch = (ct.tf([1.0, 0.0, w * w], [1.0, w / fb.notch_q, w * w]) if fb.notch_hz > 0
             else ct.tf([1.0], [1.0]))
    wz, wp = 2.0 * math.pi * fb.lead_hz, 2.0 * math.pi * fb.lag_hz
    lead = ct.tf([1.0 / wz, 1.0], [1.0 / wp, 1.0]) if fb.lead_hz > 0 else ct.tf([1.0], [1.0])
    return (float(fb.gain[axis]) * _ref_butter(fb.highpass_order, fb.highpass_hz, "highpass")
            * _ref_butter(fb.lowpass_order, fb.lowpass_hz, "lowpass") * notch * lead)


def _ref_feedforward(cfg: SystemConfig, c1: float, k1: float) -> ct.TransferFunction:
    ff = cfg.feedforward
    b, a = signal.butter(ff.highpass_order, 2.0 * math.pi * ff.highpass_hz, "highpass",
                         analog=True)
    num = ff.gain * np.polymul([c1, k1], np.trim_zeros(b, "f")[:-1])
    return ct.tf(num, a) * _ref_butter(ff.lowpass_order, ff.lowpass_hz, "lowpass")


def _ref_sos(tf: ct.TransferFunction, fs: float, prewarp_hz: float = 0.0) -> np.ndarray:
    num = np.trim_zeros(np.asarray(tf.num[0][0], float), "f")
    den = np.trim_zeros(np.asarray(tf.den[0][0], float), "f")
    if den.size == 1:
        return np.array([[num[0] / den[0], 0.0, 0.0, 1.0, 0.0, 0.0]])
    fs_eff = fs
    if prewarp_hz > 0.0:
        w0 = 2.0 * math.pi * prewarp_hz
        fs_eff = w0 / (2.0 * math.tan(w0 / (2.0 * fs)))
    return np.real(signal.zpk2sos(*signal.bilinear_zpk(*signal.tf2zpk(num, den), fs_eff)))


def _prewarp(cfg: SystemConfig, stage: int) -> float:
    n, fs = cfg.feedback[stage].notch_hz, cfg.plant.rate_hz
    return n if 0.0 < n < fs / 2 else 0.0


@pytest.mark.parametrize("path", PRESETS, ids=lambda p: p.stem)
def test_every_preset_filter_equals_scipy(path: Path) -> None:
    """Feedback per stage and axis (prewarped at the notch), feedforward per axis, geophone,
    extension, trip band-pass and disturbance bands: the sections scipy would give."""
    cfg = load_config(path)
    fs = cfg.plant.rate_hz
    built = 0
    for i in range(cfg.plant.num_stages):
        for a in range(6):
            if cfg.feedback[i].gain[a] == 0.0:
                continue
            close(to_sos(feedback_tf(cfg.feedback[i], a), fs, _prewarp(cfg, i)),
                  _ref_sos(_ref_feedback(cfg, i, a), fs, _prewarp(cfg, i)))
            built += 1
    if cfg.feedforward.gain != 0.0 and cfg.feedforward.highpass_hz > 0.0:
        for c1, k1 in suspension_totals(cfg, 1)[:3]:
            if c1 or k1:
                close(to_sos(feedforward_tf(cfg.feedforward, c1, k1), fs),
                      _ref_sos(_ref_feedforward(cfg, c1, k1), fs))
                built += 1
    s = cfg.sensors
    wn, we = 2.0 * math.pi * s.natural_frequency_hz, 2.0 * math.pi * s.extension_hz
    if s.dynamics:
        close(to_sos(geophone_tf(s), fs),
              _ref_sos(ct.tf([1.0, 0.0, 0.0], [1.0, 2.0 * s.damping_ratio * wn, wn * wn]), fs))
        built += 1
    if s.dynamics and s.extension_hz > 0.0:
        close(to_sos(extension_tf(s), fs),
              _ref_sos(ct.tf([1.0, 2.0 * s.damping_ratio * wn, wn * wn],
                             [1.0, 2.0 * s.extension_damping * we, we * we]), fs))
        built += 1
    lo, hi = cfg.control.trip_band_hz
    assert 0.0 < lo < hi < 0.95 * fs / 2  # the presets' trip is a band-pass
    close(TripMonitor(cfg.control, fs, 1).sos,
          signal.butter(2, [lo, hi], btype="bandpass", fs=fs, output="sos"))
    for band in (cfg.disturbance.ground_band_hz, cfg.disturbance.force_band_hz):
        got = band_sos(band, fs)
        assert got is not None
        close(got, signal.butter(2, list(band), btype="bandpass", fs=fs, output="sos"))
    assert built >= 3


@pytest.mark.parametrize("order", range(1, 8))
@pytest.mark.parametrize("hz", [0.02, 0.5, 3.0, 150.0, 900.0])
@pytest.mark.parametrize("btype", ["lowpass", "highpass"])
def test_analog_butterworth_equals_scipy(order: int, hz: float, btype: str) -> None:
    b, a = signal.butter(order, 2.0 * math.pi * hz, btype=btype, analog=True)
    r = fd.butter_analog(order, 2.0 * math.pi * hz, btype)
    close(r.num, np.trim_zeros(b, "f"))
    close(r.den, a)


@pytest.mark.parametrize("order", range(1, 6))
@pytest.mark.parametrize(("btype", "corner"), [
    ("lowpass", 300.0), ("lowpass", 1.0), ("highpass", 0.5), ("highpass", 700.0),
    ("bandpass", (1.0, 200.0)), ("bandpass", (0.05, 10.0)), ("bandpass", (20.0, 990.0))])
def test_digital_butterworth_and_steady_state_equal_scipy(order, btype, corner) -> None:
    fs = 2000.0
    ref = signal.butter(order, corner, btype=btype, fs=fs, output="sos")
    got = fd.butter_sos(order, corner, btype, fs)
    close(got, ref)
    close(fd.sos_steady_state(got), signal.sosfilt_zi(ref))
    f = np.geomspace(0.01, 999.0, 300)
    assert_allclose(fd.sos_response(got, f, fs), signal.sosfreqz(ref, worN=f, fs=fs)[1],
                    rtol=1e-10, atol=1e-13)


def _random_zpk(rng: np.random.Generator, nz: int, npairs: int, nreal: int
                ) -> tuple[np.ndarray, np.ndarray, float]:
    r = rng.uniform(0.05, 0.999, npairs)
    th = rng.uniform(0.01, 3.1, npairs)
    pairs = r * np.exp(1j * th)
    p = np.concatenate([pairs, pairs.conj(), rng.uniform(-0.99, 0.999, nreal)])
    zr = rng.choice([1.0, -1.0, 0.3], nz)  # zeros on the real axis, as the Tustin map gives
    return zr.astype(complex), p, float(rng.uniform(0.1, 10.0))


@pytest.mark.parametrize("seed", range(24))
def test_zpk_to_sos_pairs_and_orders_as_scipy(seed: int) -> None:
    """Random digital systems (conjugate pairs, real poles, odd orders, fewer zeros)."""
    rng = np.random.default_rng(seed)
    npairs, nreal = int(rng.integers(0, 4)), int(rng.integers(0, 4))
    npoles = 2 * npairs + nreal
    if npoles == 0:
        npairs = 1
        npoles = 2
    z, p, k = _random_zpk(rng, int(rng.integers(0, npoles + 1)), npairs, nreal)
    close(fd.zpk_to_sos(z, p, k), signal.zpk2sos(z, p, k))


@pytest.mark.parametrize(("num", "den"), [
    ([1.0, 0.0, 0.0], [1.0, 3.0, 9.0]), ([2.0, 5.0], [1.0, 7.0, 2.0, 1.0]),
    ([1e-16, 1.0, 2.0], [1.0, 1.0, 1.0]), ([3.0], [2.0, 1.0])])
@pytest.mark.parametrize("fs", [2000.0, 37.5])
def test_tf_to_zpk_and_bilinear_equal_scipy(num, den, fs) -> None:
    z, p, k = fd.tf_to_zpk(num, den)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", signal.BadCoefficients)  # the 1e-16 lead is dropped
        rz, rp, rk = signal.tf2zpk(num, den)
    close(np.sort_complex(z), np.sort_complex(rz))
    close(np.sort_complex(p), np.sort_complex(rp))
    assert_allclose(k, rk, rtol=RTOL)
    got, ref = fd.bilinear(z, p, k, fs), signal.bilinear_zpk(rz, rp, rk, fs)
    for g, r in zip(got[:2], ref[:2], strict=True):
        close(np.sort_complex(g), np.sort_complex(r))
    assert_allclose(got[2], ref[2], rtol=RTOL)


NUMBA = pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")


@pytest.mark.parametrize("filt", [sosfilt, pytest.param(fastsim.sosfilt, marks=NUMBA)],
                         ids=["python", "numba"])
@pytest.mark.parametrize("shape", [(100, 1), (100, 6), (1500, 3)])
def test_sosfilt_is_scipys_bit_for_bit(shape: tuple[int, int], filt: Any) -> None:
    """Same operations in the same order: identical numbers, state carried across blocks
    (the nodes' Python floats, the batch engine's compiled loop)."""
    sos = fd.butter_sos(2, (1.0, 200.0), "bandpass", 2000.0)
    x = np.random.default_rng(5).standard_normal(shape)
    zi = fd.sos_steady_state(sos)[:, :, None] * x[0][None, None, :]
    ref, zref = signal.sosfilt(sos, x, axis=0, zi=zi)
    y1, z1 = filt(sos, x[:37], zi)
    y2, z2 = filt(sos, x[37:], z1)
    assert_array_equal(np.vstack([y1, y2]), ref)
    assert_array_equal(z2, zref)


def test_rational_products_are_python_controls() -> None:
    """A cascade's coefficients are those of the same python-control product."""
    a, b = fd.Rational.of([1.0, 2.0], [1.0, 3.0, 5.0]), fd.Rational.of([4.0, 0.0], [1.0, 7.0])
    ref = 2.5 * ct.tf([1.0, 2.0], [1.0, 3.0, 5.0]) * ct.tf([4.0, 0.0], [1.0, 7.0])
    got = 2.5 * a * b
    assert_array_equal(got.num, ref.num[0][0])
    assert_array_equal(got.den, ref.den[0][0])
    assert (0.0 * a).is_zero()
    f = np.array([0.1, 1.0, 10.0])
    assert_allclose(got.response(f), ct.evalfr(ref, 2j * np.pi * f), rtol=1e-12)
