"""Seeded band-limited white-noise disturbances: ground velocity and table forces.

Noise comes in blocks of :data:`BLOCK` samples from a ``numpy.random.Generator`` and is
served sample by sample, so the sequence depends only on the seed, never on how callers
consume it (``next()`` per sample or ``block(n)``). A block's white noise is drawn and
band-passed when its rows are first served, :data:`CHUNK` rows at a time for ``next()``: each
source has its own generator, whose normal stream splits into consecutive draws the same way
however it is cut, and the sections carry their state from row to row, so any split gives the
same bits, and a real-time plant pays for a block in small pieces instead of in one step every
:data:`BLOCK` samples.
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.filterdesign import butter_sos
from dcsms_ros.core.sosfilter import BlockFilter, sosfilt
from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]

#: Samples drawn per refill.
BLOCK = 1024
#: Rows of a block :meth:`BandNoise.next` band-passes at once. The whole block in the step
#: that needed it took 1.0 ms (table1) and 2.6 ms (the 6-DOF TEM) of the real-time plant's
#: step once every 0.512 s at 2 kHz, and the samples after it were late; 32 rows take
#: ~50-170 us every 32nd sample for ~1-2.5 us more per sample on average (one call per chunk;
#: docs/performance.md, "A block of noise every 0.512 s").
CHUNK = 32
#: Butterworth order of each band edge.
ORDER = 2


def band_sos(band_hz: tuple[float, float] | ArrayLike, fs: float) -> Array | None:
    """Digital Butterworth SOS for the band ``[lo, hi]`` Hz at ``fs``; None for no filtering.

    ``lo <= 0`` gives a low-pass and ``hi >= fs/2`` a high-pass.
    """
    lo, hi = (float(b) for b in np.asarray(band_hz, float).ravel()[:2])
    nyq = fs / 2.0
    if hi <= lo:
        raise ConfigError(f"noise band [{lo:g}, {hi:g}] Hz: the upper edge must exceed the lower")
    if lo <= 0.0 and hi >= nyq:
        return None
    if lo <= 0.0:
        return butter_sos(ORDER, hi, "lowpass", fs)
    if hi >= nyq:
        return butter_sos(ORDER, lo, "highpass", fs)
    return butter_sos(ORDER, (lo, hi), "bandpass", fs)


def _slowest_pole_radius(sos: Array) -> float:
    return max(float(np.max(np.abs(np.roots(sec[3:])))) if np.any(sec[4:]) else 0.0
               for sec in sos)


def noise_gain(sos: Array | None) -> float:
    """Output variance per unit input variance of white noise: the impulse-response energy."""
    if sos is None:
        return 1.0
    return _noise_gain(np.ascontiguousarray(sos, dtype=np.float64).tobytes())


@functools.lru_cache(maxsize=64)
def _noise_gain(key: bytes) -> float:
    sos = np.frombuffer(key, dtype=np.float64).reshape(-1, 6).copy()
    r = _slowest_pole_radius(sos)
    # long enough for the response energy to fall below 1e-16 of its start
    n = 64 if r <= 0.0 else int(math.ceil(math.log(1e-16) / (2.0 * math.log(r)))) + 64
    imp = np.zeros(min(n, 10_000_000))
    imp[0] = 1.0
    h, _ = sosfilt(sos, imp[:, None], np.zeros((sos.shape[0], 2, 1)))
    return float(np.dot(h[:, 0], h[:, 0]))


class BandNoise:
    """Gaussian white noise through a Butterworth band-pass, scaled to a given RMS.

    Parameters
    ----------
    rms : float or array_like, shape (channels,)
        Wanted output RMS per channel (units of the output).
    band_hz : (lo, hi)
        Pass band in Hz.
    fs : float
        Sample rate in Hz.
    channels : int
    rng : numpy.random.Generator
    warm : bool
        Warm the filter up (False: only its shape is wanted, no sample will be drawn).
    block_filter : callable
        Runs the band-pass over a block (:data:`.sosfilter.BlockFilter`; the batch engine
        passes a compiled one with the same bits).

    Notes
    -----
    The filter is warmed up on discarded noise until its start transient has decayed, so the
    first sample served is already stationary.
    """

    def __init__(self, rms: float | ArrayLike, band_hz: tuple[float, float] | ArrayLike,
                 fs: float, channels: int, rng: np.random.Generator, warm: bool = True,
                 block_filter: BlockFilter = sosfilt) -> None:
        self.channels = int(channels)
        self._run = block_filter
        self._rng = rng
        self._sos = band_sos(band_hz, fs)
        self._scale = (np.broadcast_to(np.asarray(rms, float), (self.channels,))
                       / math.sqrt(noise_gain(self._sos)))
        self._zi = (None if self._sos is None
                    else np.zeros((self._sos.shape[0], 2, self.channels)))
        # the block: its rows drawn and filtered so far (0 .. _done) and their read-only view
        self._out = self._view = np.zeros((BLOCK, self.channels))
        self._done = self._k = BLOCK  # nothing drawn yet: the first sample draws
        if self._sos is not None and warm:
            r = _slowest_pole_radius(self._sos)
            n_warm = 0 if r <= 0.0 else int(math.ceil(math.log(1e-6) / math.log(r)))
            for _ in range(-(-n_warm // BLOCK)):  # the last warm block is served
                self._refill()
                self._filter(BLOCK)

    @property
    def sos(self) -> Array | None:
        """The band-pass sections (digital, at ``fs``), or None for unfiltered noise."""
        return self._sos

    @property
    def scale(self) -> Array:
        """Per channel: output = scale * (sections applied to unit-variance white noise)."""
        return np.asarray(self._scale, dtype=np.float64)

    def _refill(self) -> None:
        """Start the next block; its rows are drawn and filtered when first served. Drawing
        all 1,024 rows here made the refilling sample take ~128 us against ~20-44 us for a
        :data:`CHUNK` (table1 and tem_three_point, compiled filter; docs/performance.md,
        fortieth session)."""
        # a new array each block: rows handed out earlier (views) keep their values
        self._out = np.empty((BLOCK, self.channels))
        self._view = self._out.view()
        self._view.flags.writeable = False
        self._done = self._k = 0

    def _filter(self, n: int) -> None:
        """Draw, band-pass and scale the block's rows ``_done .. n``."""
        lo = self._done
        w = self._rng.standard_normal((n - lo, self.channels))
        if self._sos is not None and self._zi is not None:
            w, self._zi = self._run(self._sos, w, self._zi)
        self._out[lo:n] = w * self._scale
        self._done = n

    def next(self) -> Array:
        """The next sample, shape (channels,) (read-only view)."""
        k = self._k
        if k >= self._done:
            if k >= BLOCK:
                self._refill()
                k = 0
            self._filter(min(k + CHUNK, BLOCK))
        self._k = k + 1
        return self._view[k]

    def block(self, n: int) -> Array:
        """The next ``n`` samples, shape (n, channels); same values as ``n`` calls of next()."""
        out = np.empty((n, self.channels))
        i = 0
        while i < n:
            if self._k >= BLOCK:
                self._refill()
            m = min(n - i, BLOCK - self._k)
            if self._done < self._k + m:
                self._filter(self._k + m)
            out[i:i + m] = self._out[self._k:self._k + m]
            self._k += m
            i += m
        return out


class Disturbances:
    """Ground velocity and table-force disturbances of one run.

    Parameters
    ----------
    cfg : SystemConfig
        Uses ``cfg.disturbance`` and ``cfg.plant`` (rate, stages, dof).
    seed : int or numpy.random.SeedSequence, optional
        Defaults to ``cfg.disturbance.seed``; the ground and force streams are independent
        children (``SeedSequence(seed).spawn(2)``).
    ground : array_like, shape (K, dof) or (K,) for 1dof, optional
        Recorded ground twist (m/s, rad/s) replayed instead of the ground noise. It loops when
        it ends and ``ground_exhausted`` becomes True (a warning is issued once).
    table : array_like, shape (K, N, dof), optional
        Wrenches (N, N*m) added to the random table forces of samples 0 .. K-1 (an impulse, a
        test signal); nothing is added after them.
    warm : bool
        False builds the sources without warming their filters up: for their shapes only
        (:mod:`.spectra`); drawing from them then starts with a transient.
    block_filter : callable
        As for :class:`BandNoise`.
    """

    def __init__(self, cfg: SystemConfig, seed: int | np.random.SeedSequence | None = None,
                 ground: ArrayLike | None = None, table: ArrayLike | None = None,
                 warm: bool = True, block_filter: BlockFilter = sosfilt) -> None:
        d = cfg.disturbance
        fs = cfg.plant.rate_hz
        self.dof = cfg.plant.dof
        self.num_stages = cfg.plant.num_stages
        ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(
            d.seed if seed is None else int(seed))
        g_ss, f_ss = ss.spawn(2)
        self._ntrans = 1 if self.dof == 1 else 3
        self._ground: Array | None = None
        self._gnoise: BandNoise | None = None
        if ground is not None:
            g = np.asarray(ground, dtype=np.float64)
            if g.ndim == 1 and self.dof == 1:
                g = g[:, None]
            if g.ndim != 2 or g.shape[1] != self.dof or g.shape[0] == 0:
                raise ConfigError(f"ground replay: expected shape (K, {self.dof}), got "
                                  f"{np.shape(ground)}")
            if not np.isfinite(g).all():
                raise ConfigError("ground replay: contains NaN or Inf")
            self._ground = g
        else:
            rms = d.ground_rms_mps[2:3] if self.dof == 1 else d.ground_rms_mps
            self._gnoise = BandNoise(rms, d.ground_band_hz, fs, self._ntrans,
                                     np.random.default_rng(g_ss), warm, block_filter)
        self._fnoise = BandNoise(d.force_rms_n, d.force_band_hz, fs,
                                 self.num_stages * self._ntrans, np.random.default_rng(f_ss), warm,
                                 block_filter)
        self._table: Array | None = None
        if table is not None:
            tab = np.asarray(table, dtype=np.float64)
            if tab.ndim != 3 or tab.shape[1:] != (self.num_stages, self.dof):
                raise ConfigError(f"table wrench: expected shape (K, {self.num_stages}, "
                                  f"{self.dof}), got {tab.shape}")
            if not np.isfinite(tab).all():
                raise ConfigError("table wrench: contains NaN or Inf")
            self._table = tab
        self.k = 0
        self.ground_exhausted = False

    @property
    def translations(self) -> int:
        """Axes driven per body: 1 (z) in 1dof, 3 (x y z) in 6dof; rotations are never driven."""
        return self._ntrans

    @property
    def ground_noise(self) -> BandNoise | None:
        """The ground-velocity noise source (None when a record is replayed)."""
        return self._gnoise

    @property
    def force_noise(self) -> BandNoise:
        """The table-force noise source, channels stage by stage, translations per stage."""
        return self._fnoise

    def next(self) -> tuple[Array, Array]:
        """Disturbances of the next sample.

        Returns
        -------
        ground_twist : ndarray, shape (dof,)
            Ground velocity at the world origin, m/s (rotations zero).
        table_wrench : ndarray, shape (N, dof)
            Force on each stage at its reference point, N (moments zero).
        """
        g = np.zeros(self.dof)
        if self._ground is not None:
            k = self.k % self._ground.shape[0]
            if k == 0 and self.k > 0 and not self.ground_exhausted:
                self.ground_exhausted = True
                warnings.warn("ground replay ended; looping from its start", RuntimeWarning,
                              stacklevel=2)
            g[:] = self._ground[k]
        else:
            assert self._gnoise is not None
            g[:self._ntrans] = self._gnoise.next()
        w = np.zeros((self.num_stages, self.dof))
        w[:, :self._ntrans] = self._fnoise.next().reshape(self.num_stages, self._ntrans)
        if self._table is not None and self.k < self._table.shape[0]:
            w += self._table[self.k]
        self.k += 1
        return g, w

    def block(self, n: int) -> tuple[Array, Array]:
        """The next ``n`` samples at once, the same values as ``n`` calls of :meth:`next`.

        Returns
        -------
        ground_twist : ndarray, shape (n, dof)
        table_wrench : ndarray, shape (n, N, dof)
        """
        g = np.zeros((n, self.dof))
        if self._ground is not None:
            size = self._ground.shape[0]
            j = self.k + np.arange(n)
            if not self.ground_exhausted and np.any((j >= size) & (j % size == 0)):
                self.ground_exhausted = True
                warnings.warn("ground replay ended; looping from its start", RuntimeWarning,
                              stacklevel=2)
            g[:] = self._ground[j % size]
        else:
            assert self._gnoise is not None
            g[:, :self._ntrans] = self._gnoise.block(n)
        w = np.zeros((n, self.num_stages, self.dof))
        w[:, :, :self._ntrans] = self._fnoise.block(n).reshape(n, self.num_stages,
                                                                self._ntrans)
        if self._table is not None and self.k < self._table.shape[0]:
            m = min(n, self._table.shape[0] - self.k)
            w[:m] += self._table[self.k:self.k + m]
        self.k += n
        return g, w


__all__ = ["BLOCK", "CHUNK", "BandNoise", "Disturbances", "band_sos", "noise_gain"]
