"""VC-A ... VC-G verdicts on synthetic one-third-octave spectra."""

from __future__ import annotations

import numpy as np
import pytest

from dcsms_ros.analysis.criteria import CRITERIA, evaluate
from dcsms_ros.analysis.estimators import third_octave_bands

C = third_octave_bands(1.0, 80.0)[:, 0]


@pytest.mark.parametrize("level_um,expected", [
    (40.0, "VC-A"), (20.0, "VC-B"), (10.0, "VC-C"), (5.0, "VC-D"), (3.0, "VC-E"),
    (1.5, "VC-F"), (0.5, "VC-G"), (60.0, None)])
def test_flat_spectrum(level_um: float, expected: str | None) -> None:
    """A flat spectrum meets exactly the criteria whose limit is above it (8-80 Hz rule)."""
    rms = np.full(C.size, level_um * 1e-6)
    rms[C < 8] = 0.1e-6  # keep the low-frequency A/B acceleration branch out of it
    assert evaluate(C, rms).best == expected


def test_low_frequency_acceleration_branch() -> None:
    """80 um/s at 4 Hz meets VC-A (260 ug: ~101 um/s) but not VC-B (~51 um/s)."""
    rms = np.full(C.size, 0.1e-6)
    rms[np.argmin(np.abs(C - 4.0))] = 80e-6
    v = evaluate(C, rms)
    assert v.best == "VC-A" and abs(v.worst_band_hz - 4.0) < 0.1 and v.margin_db > 0
    vc_a = CRITERIA[0]
    expected = 260e-6 * 9.80665 / (2 * np.pi * 6.3)  # constant acceleration below 8 Hz
    assert abs(vc_a.limit(np.array([6.3]))[0] / expected - 1) < 1e-12
    assert vc_a.limit(np.array([8.0]))[0] == 50e-6
    assert vc_a.limit(np.array([1.0]))[0] == vc_a.limit(np.array([4.0]))[0]


def test_one_band_decides() -> None:
    """A single band over VC-E in an otherwise VC-G spectrum gives VC-D, naming that band."""
    rms = np.full(C.size, 0.5e-6)
    rms[np.argmin(np.abs(C - 20.0))] = 4e-6
    v = evaluate(C, rms)
    assert v.best == "VC-D" and abs(v.worst_band_hz - 20.0) < 0.1
