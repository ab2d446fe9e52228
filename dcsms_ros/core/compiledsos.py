"""scipy.signal's compiled ``sosfilt`` as a :data:`.sosfilter.BlockFilter`, for the batch
engine's object path and where numba is not installed.

The nodes filter blocks with :func:`.sosfilter.sosfilt` (Python floats, no scipy.signal to
import at start-up); the engine filters the trip's, the checkpoints' and the disturbances'
blocks 10-20x faster with scipy's C loop, or, on its fast path, with the numba loop of
:func:`.fastsim.sosfilt` (scipy validates its arguments for ~80 us a call, longer than a 50 ms
block of a few channels takes to filter). All run the same operations in the same order, so a
graph and the batch engine still agree bit for bit (``test/core/test_filterdesign.py``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import signal

Array = NDArray[np.float64]


def sosfilt(sos: Array, x: Array, zi: Array) -> tuple[Array, Array]:
    """:func:`.sosfilter.sosfilt` (same arguments, same numbers) in compiled code."""
    y, zf = signal.sosfilt(sos, x, axis=0, zi=zi)
    return np.asarray(y, dtype=np.float64), np.asarray(zf, dtype=np.float64)


__all__ = ["sosfilt"]
