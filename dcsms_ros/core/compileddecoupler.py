"""The decoupling node's per-sample work in one numba-compiled call, the same numbers.

:meth:`.Decoupler.step` is an extension filter and one small matrix product per body, ~10 numpy
calls a sample; :class:`CompiledDecoupler` runs the same operations in the same order in
:func:`.fastloop.decouple_sample` (the decoupler part of the batch engine's fused loop,
bit-identical to the object path). A sample with a non-finite reading takes the object's own
path (it holds that body's filter states), on the same state arrays.

:func:`decoupler` builds one when numba is there (:func:`.fastsim.available`), else a
:class:`.Decoupler`; the kernel is compiled (or loaded from numba's cache) when it is built.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.decoupling import Array, Decoupler
from dcsms_ros.core.fastsim import available, gemv_layout


class CompiledDecoupler(Decoupler):
    """A :class:`.Decoupler` whose :meth:`step` runs compiled; the same values and counter."""

    def __init__(self, cfg: SystemConfig) -> None:
        from dcsms_ros.core.fastloop import decouple_sample  # noqa: PLC0415 - optional: numba

        super().__init__(cfg)
        self._kernel = decouple_sample
        blocks = self.blocks
        self._starts = np.array([sl.start for sl, _ in blocks] + [blocks[-1][0].stop], np.int64)
        self._pinvs = tuple(gemv_layout(m) for _, m in blocks)
        self._ext_arrays = tuple(self.extension.arrays)
        self._vext = np.zeros(self.n_channels)
        saved = self._ext_arrays[5].copy()  # compile (or load) now, not at the first sample
        self._kernel(self._ext_arrays, self._starts, self._pinvs, self._vext,
                     np.zeros(self.n_channels), np.zeros_like(self._out))
        np.copyto(self._ext_arrays[5], saved)

    def step(self, raw: ArrayLike) -> Array:
        """As :meth:`.Decoupler.step` (a new array, the same values)."""
        x = np.asarray(raw, dtype=np.float64)
        if x.ndim == 1 and x.shape[0] == self._vext.shape[0] and self._kernel(
                self._ext_arrays, self._starts, self._pinvs, self._vext, x, self._out):
            return self._out.copy()
        return super().step(x)


def decoupler(cfg: SystemConfig) -> Decoupler:
    """A :class:`CompiledDecoupler` when numba is there, else a :class:`.Decoupler`."""
    return CompiledDecoupler(cfg) if available() else Decoupler(cfg)


__all__ = ["CompiledDecoupler", "decoupler"]
