"""Trip checkpoints: the verdict depends on the samples, never on how they are fed."""

from __future__ import annotations

import numpy as np
import pytest

from dcsms_ros.core.compiledsos import sosfilt as compiled
from dcsms_ros.core.config import ControlConfig
from dcsms_ros.core.sosfilter import sosfilt
from dcsms_ros.core.trip import TripChecker, check_samples


def _velocity(n: int, grow_from: int) -> np.ndarray:
    """Two stages, 1 dof: noise, then a 5 Hz oscillation growing 20 /s from ``grow_from``."""
    rng = np.random.default_rng(3)
    v = 1e-6 * rng.standard_normal((n, 2, 1))
    t = np.arange(n - grow_from) / 2000.0
    v[grow_from:, 1, 0] += 1e-6 * np.exp(20 * t) * np.sin(2 * np.pi * 5 * t)
    return v


@pytest.mark.parametrize("blocks", [[5000], [1, 99, 4900], [37] * 135 + [5], [100] * 50])
def test_trip_sample_does_not_depend_on_block_sizes(blocks):
    """Fed in any blocks, the checker trips at the same checkpoint with the same RMS."""
    v = _velocity(5000, 1000)
    ref = TripChecker(ControlConfig(), 2000.0, 2, 1)
    used, trip_ref = ref.push(v)
    assert trip_ref is not None and used == trip_ref.sample + 1
    assert (trip_ref.sample + 1) % check_samples(2000.0) == 0
    c = TripChecker(ControlConfig(), 2000.0, 2, 1)
    pos = 0
    trip = None
    for b in blocks:
        used, trip = c.push(v[pos:pos + b])
        pos += used
        if trip is not None:
            break
    assert trip == trip_ref
    assert trip.stage == 2 and trip.rms > ControlConfig().trip_rms_mps


def test_clone_judges_without_committing():
    """A clone advances on its own; the original still judges the same samples alike."""
    v = _velocity(3000, 500)
    c = TripChecker(ControlConfig(), 2000.0, 2, 1)
    c.push(v[:1000])
    trial = c.clone()
    _, t1 = trial.push(v[1000:])
    _, t2 = c.push(v[1000:])
    assert t1 == t2 and t1 is not None


def test_compiled_block_filter_gives_the_same_trip_bit_for_bit():
    """The batch engine's compiled block filter and the nodes' Python one: the same trip
    sample and the same RMS, to the last bit."""
    v = _velocity(5000, 1000)
    got = [TripChecker(ControlConfig(), 2000.0, 2, 1, f).push(v) for f in (sosfilt, compiled)]
    (used_a, trip_a), (used_b, trip_b) = got
    assert trip_a is not None and trip_b is not None
    assert (used_a, trip_a.sample, trip_a.rms) == (used_b, trip_b.sample, trip_b.rms)
