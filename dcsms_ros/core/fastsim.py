"""Fast path of the batch engine: the core step objects' arrays driven by :mod:`.fastloop`.

The objects are built exactly as for the object path (:class:`.engine.Simulation`); this module
reads their coefficients and states only through their documented array API
(:attr:`.SosFilter.arrays`, :attr:`.DiscretePlant.a`/``b``/``c``/``x``,
:attr:`.PlantSimulator.channel_matrix`/``sample_inputs``, :attr:`.Decoupler.extension`/``blocks``,
the loops' ``filter``/``axes``/``saved_state``/``allocator``/``fader``). The states are the
objects' own arrays, advanced in place. It feeds the compiled loop the disturbances, replayed
ground and geophone noise that the objects themselves draw, block by block
(:meth:`.Disturbances.block`, :meth:`.GeophoneArray.noise_block`). Between blocks only the fader
targets change.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.core.modes import ControllerId
from dcsms_ros.core.simulator import PlantSimulator

Array = NDArray[np.float64]
Loop = Any  # FeedbackLoop | FeedforwardLoop

#: Samples per compiled call when nothing else splits the run (bounds the noise buffers).
BLOCK = 1 << 16


def available() -> bool:
    """True when numba can be imported (the fast paths are optional: the engine and the nodes
    step the objects without it)."""
    return importlib.util.find_spec("numba") is not None


def sosfilt(sos: ArrayLike, x: ArrayLike, zi: ArrayLike) -> tuple[Array, Array]:
    """:func:`.sosfilter.sosfilt` (same arguments, same numbers) in numba-compiled code, the
    batch engine's block filter when numba is there (:func:`available`): the engine filters
    the disturbances', the trip's and the checkpoints' 50 ms blocks, ~6,000 calls per simulated
    minute of table1, where ``scipy.signal.sosfilt`` spends ~80 us a call validating its
    arguments before its C loop runs."""
    from dcsms_ros.core.fastloop import sosfilt_block  # noqa: PLC0415 - optional: numba

    s = np.ascontiguousarray(sos, dtype=np.float64).reshape(-1, 6)
    if np.any(s[:, 3] != 1.0):
        raise ValueError("sosfilt: a0 of every section must be 1")
    xs = np.ascontiguousarray(x, dtype=np.float64)
    zf = np.array(zi, dtype=np.float64, copy=True, order="C")
    y = np.empty_like(xs)
    sosfilt_block(s, xs, zf, y)
    return y, zf


def _c(a: Any, dtype: Any = np.float64) -> Any:
    return np.ascontiguousarray(a, dtype=dtype)


def gemv_layout(a: Any) -> Any:
    """A matrix in the memory layout the object multiplies with (numpy picks the BLAS ``gemv``
    variant from it, so keeping C or Fortran order keeps the products bit-identical)."""
    a = np.asarray(a, dtype=np.float64)
    return a if a.flags.c_contiguous or a.flags.f_contiguous else np.ascontiguousarray(a)


class Inputs:
    """Disturbances, replayed ground, geophone noise and excitation of a block of samples, as
    drawn by the objects: ``ground`` (m, dof), ``table`` (m, N*dof), ``noise`` (m, n_ch or 0),
    ``excite`` (m, N*dof, or m x 0 for a run without excitation)."""

    def __init__(self, ground: Array, table: Array, noise: Array,
                 excite: Array | None = None) -> None:
        self.ground, self.table, self.noise = ground, table, noise
        self.excite = np.zeros((ground.shape[0], 0)) if excite is None else excite

    def rows(self, i0: int, i1: int) -> Inputs:
        """Rows ``i0 .. i1-1`` (views)."""
        return Inputs(self.ground[i0:i1], self.table[i0:i1], self.noise[i0:i1],
                      self.excite[i0:i1])


class FastLoop:
    """The arrays of one closed loop (plant simulator, decoupler, controllers) for the kernel.

    Parameters
    ----------
    sim, dec : PlantSimulator, Decoupler
        Freshly built objects (sample 0 drawn, filters at rest); their states advance in place.
    ctrls : mapping of controller id to loop
        In the order the engine steps them.
    body : mapping of controller id to int
        Index of the body whose twist each controller reads.
    """

    def __init__(self, sim: PlantSimulator, dec: Decoupler, ctrls: Mapping[str, Loop],
                 body: Mapping[str, int]) -> None:
        self.sim, self.ids = sim, list(ctrls)
        p = sim.plant
        n_out, nx = p.c.shape
        chan = sim.channel_matrix
        self.plant = (p.a, p.b, p.c, gemv_layout(chan), p.x, np.zeros(n_out), np.zeros(nx),
                      np.zeros(nx), np.zeros(p.n_inputs), np.zeros(chan.shape[1]),
                      np.zeros(chan.shape[0]))
        self.geo = tuple(sim.geophones.filter.arrays)
        self.ext = tuple(dec.extension.arrays)
        blocks = dec.blocks
        starts = [sl.start for sl, _ in blocks] + [blocks[-1][0].stop]
        self.dec = (np.asarray(starts, np.int64), tuple(gemv_layout(m) for _, m in blocks),
                    tuple(np.zeros(sl.stop - sl.start) for sl, _ in blocks),
                    np.zeros(chan.shape[0]))
        loops = list(ctrls.values())
        filt = [c.filter.arrays for c in loops]
        self.ctl = (*(tuple(f[j] for f in filt) for j in range(6)),
                    tuple(c.saved_state for c in loops),
                    tuple(_c(c.axes, np.int64) for c in loops),
                    tuple(gemv_layout(c.allocator.pinv) for c in loops),
                    tuple(gemv_layout(c.allocator.b) for c in loops),
                    tuple(np.zeros(len(c.axes)) for c in loops),
                    tuple(np.zeros(c.allocator.n_act) for c in loops),
                    np.array([c.allocator.limit for c in loops]),
                    np.array([body[cid] for cid in ctrls], np.int64),
                    np.array([ControllerId.parse(cid).stage - 1 for cid in ctrls], np.int64),
                    np.zeros((len(loops), sim.dof)))
        self.fade = (np.array([c.fader.steps for c in loops], np.int64),
                     np.array([c.fader.count for c in loops], np.int64),
                     np.array([c.fader.target for c in loops], np.int64))
        self.counters = np.zeros(2, np.int64)
        self.alloc = (tuple(gemv_layout(a.pinv) for a in sim.allocators),
                      np.array([a.limit for a in sim.allocators]),
                      tuple(np.zeros(a.n_act) for a in sim.allocators),
                      np.zeros((len(sim.allocators), sim.dof)), self.counters)
        self._first = True
        # every array the kernel advances: a snapshot of them is the loop's whole state
        self._state = [p.x, self.geo[5], self.ext[5], *self.ctl[5], self.fade[1],
                       self.counters]

    def set_targets(self, on: frozenset[str]) -> None:
        """Fader targets of every controller (a mode switch)."""
        self.fade[2][:] = [cid in on for cid in self.ids]

    def draw(self, m: int, excite: Array | None = None) -> Inputs:
        """The objects' inputs for the next ``m`` samples; ``excite`` (m, N, dof) is the
        excitation of those samples (None: the run has none)."""
        sim = self.sim
        assert sim.disturbances is not None
        if self._first:  # sample 0 was drawn when the simulator was built
            self._first = False
            g, w = sim.disturbances.block(m - 1)
            g0, w0 = sim.sample_inputs
            g = np.vstack([g0[None, :], g])
            w = np.concatenate([w0[None], w])
        else:
            g, w = sim.disturbances.block(m)
        noise = sim.geophones.noise_block(m)
        if sim.geophones.noise_std <= 0.0:
            noise = np.zeros((m, 0))
        exc = None if excite is None else _c(np.reshape(excite, (m, -1)))
        return Inputs(g, _c(w.reshape(m, -1)), noise, exc)

    def snapshot(self) -> list[Array]:
        """Copies of every state the kernel advances."""
        return [s.copy() for s in self._state]

    def restore(self, snap: list[Array]) -> None:
        """Put a :meth:`snapshot` back (in place: the objects share these arrays)."""
        for s, v in zip(self._state, snap, strict=True):
            np.copyto(s, v)

    def run(self, inputs: Inputs, out: tuple[Array, ...]) -> int:
        """Run one sample per input row into the rows of ``out`` (truth, raw, velocity,
        wrench (nc, m, dof), applied); returns the rows done (fewer: a non-finite value)."""
        from dcsms_ros.core.fastloop import run_block  # noqa: PLC0415 - optional: numba

        m = inputs.ground.shape[0]
        return int(run_block(0, m, self.plant, self.geo, self.ext, self.dec, self.ctl,
                             self.fade, self.alloc, inputs.ground, inputs.table, inputs.noise,
                             inputs.excite, out))

    def sync(self, k: int) -> None:
        """Tell the plant simulator it is at sample ``k`` and copy the saturation count."""
        self.sim.k = k
        self.sim.saturations = int(self.counters[1])


__all__ = ["BLOCK", "FastLoop", "Inputs", "available", "gemv_layout", "sosfilt"]
