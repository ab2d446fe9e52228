"""The plant simulator node's per-sample work in numba-compiled kernels, the same numbers.

A graph's plant steps one sample per call: :meth:`.PlantSimulator.measure` and
:meth:`.PlantSimulator.advance` are some fifty numpy calls on arrays of a few elements,
~21 us a sample on table1, ~18 % of the composed lockstep step (py-spy, 2026-12-03).
:class:`CompiledPlant` runs the same floating-point operations in the same order in one
compiled kernel call a sample (:func:`.fastloop.plant_sample`: the plant part of the batch
engine's fused loop, which is bit-identical to the object path; 6.6 us a sample), and
draws the disturbances and the geophone noise in blocks (:meth:`.Disturbances.block`,
:meth:`.GeophoneArray.noise_block`: the same values as sample by sample), their band-passes
run by the compiled block filter (:func:`.fastsim.sosfilt`, the same bits). What differs: the
readings :meth:`measure` returns are a buffer of the plant's (valid until the next sample),
and a replayed ground's end is warned about when its block is drawn.

:func:`plant_simulator` builds one when numba is there (:func:`.fastsim.available`), else a
:class:`.PlantSimulator`; the kernel is compiled (~2 s, once after an install) or loaded from
numba's cache (~0.3 s with numba's import) when it is built, not at the first sample.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.fastsim import available, gemv_layout, sosfilt
from dcsms_ros.core.simulator import PlantSimulator

Array = NDArray[np.float64]

#: Samples of disturbances and geophone noise drawn at once (0.128 s at 2 kHz). A draw holds
#: up the sample that makes it: 1,024 samples band-passed by the nodes' Python filter took
#: 0.75-1.1 ms on table1 and 2.2-2.4 ms on tem_three_point, every 0.5 s a sample or more
#: past its deadline in real time; with the compiled filter the longest sample of 8,192 is
#: 0.11-0.12 ms on table1 and 0.35-0.41 ms on tem_three_point at 256 (the white noise's own
#: 1,024-row draws, which the object path makes too), 0.15-0.28 and 0.48-0.73 ms at 1,024.
DRAW_BLOCK = 256


class CompiledPlant(PlantSimulator):
    """A :class:`.PlantSimulator` whose ``truth``, ``measure`` and ``advance`` run compiled;
    the same parameters, values and counters. One kernel call a sample: the advance of
    sample k and the readings of sample k+1."""

    # what a call that only measures passes for the advance's arguments
    _no_rows = np.zeros((0, 1))
    _no_stage = np.zeros(0, np.int64)
    _no_applied = np.zeros(0)

    def __init__(self, cfg: SystemConfig, **kwargs: Any) -> None:
        from dcsms_ros.core.fastloop import plant_sample  # noqa: PLC0415 - optional: numba

        self._kernel = plant_sample
        self._row = self._block_len = -1  # the base's __init__ draws sample 0: the first block
        kwargs.setdefault("block_filter", sosfilt)
        super().__init__(cfg, **kwargs)
        p, chan = self.plant, self.channel_matrix
        nst, dof = cfg.plant.num_stages, self.dof
        self._mats = (p.a, p.b, p.c, gemv_layout(chan))
        o_t = p.c.shape[0] + 2 * p.a.shape[0] + p.n_inputs  # the kernel's scratch layout
        o_c = o_t + (nst + 1) * dof
        self._work = np.zeros(o_c + chan.shape[0] + nst * dof + self._n_act)
        self._truth = self._work[o_t:o_c].reshape(nst + 1, dof)
        self._readings = self._work[o_c:o_c + chan.shape[0]]
        self._geo = tuple(self.geophones.filter.arrays)
        self._pinvs = tuple(gemv_layout(a.pinv) for a in self.allocators)
        self._limits = np.array([a.limit for a in self.allocators])
        self._counters = np.zeros(2, np.int64)
        self._no_excite = np.zeros((0, 0))
        self._by_ids: dict[tuple[str, ...], tuple[Array, NDArray[np.int64]]] = {}
        self._warm_up()

    def _call(self, rows: Array, stage: NDArray[np.int64], excite: Array, r: int, rn: int,
              applied: Array) -> int:
        return int(self._kernel(self._mats, self.plant.x, self._work, self._geo, self._pinvs,
                                self._limits, self._counters, rows, stage, excite,
                                self._g_rows, self._d_rows, self._n_rows, r, rn, applied))

    def _warm_up(self) -> None:
        """Compile the kernel (or load it from numba's cache) on copies of the state."""
        state = [self.plant.x, self._geo[5], self._counters]
        saved = [a.copy() for a in state]
        self._call(np.zeros((1, self.dof)), np.zeros(1, np.int64), self._no_excite, 0, 0,
                   np.empty(self._n_act))
        for a, v in zip(state, saved, strict=True):
            np.copyto(a, v)

    @property
    def sample_inputs(self) -> tuple[Array, Array]:
        """As :attr:`.PlantSimulator.sample_inputs` (views of the drawn block)."""
        n = self.cfg.plant.num_stages
        return self._g_rows[self._row], self._d_rows[self._row].reshape(n, self.dof)

    # -- the sample's inputs, drawn in blocks ------------------------------------------------
    def _draw(self) -> None:
        self._raw = None
        self._row += 1
        if 0 <= self._row < self._block_len:
            return
        cfg = self.cfg.plant
        if self.disturbances is None:
            g = np.zeros((DRAW_BLOCK, cfg.dof))
            w = np.zeros((DRAW_BLOCK, cfg.num_stages, cfg.dof))
        else:
            g, w = self.disturbances.block(DRAW_BLOCK)
        self._g_rows = np.ascontiguousarray(g)
        self._d_rows = np.ascontiguousarray(w.reshape(DRAW_BLOCK, -1))
        self._n_rows = self.geophones.noise_block(DRAW_BLOCK)
        if self.geophones.noise_std <= 0.0:
            self._n_rows = np.zeros((DRAW_BLOCK, 0))
        self._row, self._block_len = 0, DRAW_BLOCK

    # -- per sample ----------------------------------------------------------------------------
    def truth(self) -> Array:
        """True twists of ground and stages at sample k, shape (N+1, dof), m/s and rad/s
        (the plant's buffer: copy to keep)."""
        self.measure()
        return self._truth

    def measure(self) -> Array:
        """Geophone readings at sample k, shape (n_channels,), m/s (the plant's buffer,
        valid until the next sample)."""
        if self._raw is None:
            self._call(self._no_rows, self._no_stage, self._no_excite, -1, self._row,
                       self._no_applied)
            self._raw = self._readings
        return self._raw

    def _wrench_rows(self, wrenches: Mapping[str, Any]) -> tuple[Array, NDArray[np.int64]]:
        """The wrenches as rows in their order, and each one's stage row."""
        ids = tuple(wrenches)
        got = self._by_ids.get(ids)
        if got is None:
            got = self._by_ids[ids] = (np.zeros((len(ids), self.dof)),
                                       np.array([self._row_of(c) for c in ids], np.int64))
        rows, dof = got[0], self.dof
        for i, (cid, w) in enumerate(wrenches.items()):
            # a node's forces are tuples of floats (read_stamped_floats): no array made
            v = w if w.__class__ is tuple or (w.__class__ is np.ndarray and w.ndim == 1) \
                else np.ravel(w)
            if len(v) != dof:
                raise ValueError(f"{cid}: wrench of {len(v)} components, the plant has "
                                 f"{dof} degrees of freedom")
            rows[i] = v
        return got

    def advance(self, wrenches: Mapping[str, Any], excitation: Array | None = None) -> Array:
        """As :meth:`.PlantSimulator.advance` (the same values, counters and errors)."""
        if self._raw is None:
            self.measure()
        rows, stage = self._wrench_rows(wrenches)
        exc = self._no_excite
        if excitation is not None:
            exc = np.ascontiguousarray(excitation, dtype=np.float64).reshape(
                self.cfg.plant.num_stages, self.dof)
        applied = np.empty(self._n_act)
        sat = self._counters[1]
        g_rows, d_rows, r = self._g_rows, self._d_rows, self._row
        self.k += 1
        self._draw()
        # the next sample's readings in the same call, unless its inputs are a new block
        same = self._g_rows is g_rows
        self.nonfinite_inputs += self._kernel(
            self._mats, self.plant.x, self._work, self._geo, self._pinvs, self._limits,
            self._counters, rows, stage, exc, g_rows, d_rows, self._n_rows, r,
            self._row if same else -1, applied)
        self.saturations += int(self._counters[1] - sat)
        if same:
            self._raw = self._readings
        return applied


def plant_simulator(cfg: SystemConfig, **kwargs: Any) -> PlantSimulator:
    """A :class:`CompiledPlant` when numba is there, else a :class:`.PlantSimulator`; the same
    arguments."""
    return CompiledPlant(cfg, **kwargs) if available() else PlantSimulator(cfg, **kwargs)


__all__ = ["DRAW_BLOCK", "CompiledPlant", "plant_simulator"]
