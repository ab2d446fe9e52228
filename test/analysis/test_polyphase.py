"""The numpy polyphase resampler against scipy.signal.resample_poly(padtype="line")."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from dcsms_ros.analysis.polyphase import CHUNK, lowpass_taps, resample_poly


@pytest.mark.parametrize(("up", "down"), [(1, 2), (2, 1), (3, 2), (2, 5), (1, 4), (5, 4),
                                           (4, 6), (1, 1)])
@pytest.mark.parametrize("k", [2, 37, 1000])
def test_equals_scipy_resample_poly(up: int, down: int, k: int) -> None:
    """A random walk with an offset (the line extension matters at both ends): same length,
    same values to ~1e-14 of the signal's scale."""
    x = np.cumsum(np.random.default_rng(k + up).standard_normal((k, 3)), axis=0) + 5.0
    ref = signal.resample_poly(x, up, down, axis=0, padtype="line")
    got = resample_poly(x, up, down)
    assert got.shape == ref.shape
    assert_allclose(got, ref, rtol=0.0, atol=1e-14 * float(np.max(np.abs(ref))))


def test_long_record_spans_chunks() -> None:
    x = np.sin(np.linspace(0.0, 40.0, 3 * CHUNK // 2))[:, None] * [1.0, -2.0]
    ref = signal.resample_poly(x, 3, 2, axis=0, padtype="line")
    assert_allclose(resample_poly(x, 3, 2), ref, rtol=0.0, atol=1e-14)


@pytest.mark.parametrize(("up", "down"), [(1, 2), (3, 2), (2, 7)])
def test_taps_are_scipys_kaiser_firwin(up: int, down: int) -> None:
    rate = max(up, down)
    ref = signal.firwin(20 * rate + 1, 1.0 / rate, window=("kaiser", 5.0)) * up
    assert_allclose(lowpass_taps(up, down), ref, rtol=0.0, atol=1e-15 * up)
