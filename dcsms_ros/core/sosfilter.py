"""Second-order sections run sample by sample: :class:`SosFilter`, vectorised over channels,
without hidden state, and its exact state-space form (:func:`sos_state_space`).

The sections come from :func:`.filters.to_sos`; the batch engine's compiled loop advances the
same arrays (:class:`SosArrays`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.filterdesign import sos_steady_state

Array = NDArray[np.float64]

#: A block filter ``(sos (n, 6), x (K, channels), zi (n, 2, channels)) -> (y, zf)`` with the
#: operations of :func:`sosfilt`: it, or a compiled one that gives the same bits.
BlockFilter = Callable[[Array, Array, Array], tuple[Array, Array]]

#: Largest channels x sections a :class:`SosFilter` steps on Python floats (numpy beyond: one
#: numpy call per section costs ~1 us, one float section ~0.25 us per channel).
SCALAR_MAX = 12


def flat(a: Array) -> memoryview[float]:
    """A flat view of C-contiguous float64 ``a`` (its memory, not a copy) whose items read
    and write as Python floats."""
    if not a.flags.c_contiguous:
        raise ValueError("flat: the array must be C-contiguous")
    return cast("memoryview[float]", memoryview(a.reshape(-1)))  # type: ignore[arg-type]


class SosArrays(NamedTuple):
    """The arrays a :class:`SosFilter` runs on: the filter's own arrays, not copies.

    A kernel that advances ``state`` in place with the recursion of :meth:`SosFilter.step`
    (transposed direct form II, section by section, channel by channel) advances the filter.

    Attributes
    ----------
    b0, b1, b2, a1, a2 : ndarray, shape (n_sections, channels)
        Coefficients normalised by ``a0`` (C-contiguous; do not write).
    state : ndarray, shape (n_sections, 2, channels)
        The delay states (units of the filter's output).
    """

    b0: Array
    b1: Array
    b2: Array
    a1: Array
    a2: Array
    state: Array


class SosFilter:
    """Cascade of second-order sections, transposed direct form II, vectorised over channels.

    Parameters
    ----------
    sos : array_like, shape (n, 6) or (channels, n, 6)
        Sections shared by every channel, or one set per channel (same section count).
    channels : int
        Number of independent channels filtered in parallel.
    """

    def __init__(self, sos: ArrayLike, channels: int) -> None:
        s = np.asarray(sos, dtype=np.float64)
        if s.ndim == 2:
            s = np.broadcast_to(s, (channels, *s.shape))
        if s.ndim != 3 or s.shape[0] != channels or s.shape[2] != 6:
            raise ValueError(f"SosFilter: sos must be (n, 6) or ({channels}, n, 6), "
                             f"got {np.shape(sos)}")
        s = s / s[:, :, 3:4]  # normalise a0 so step() matches sosfilt
        # coefficient arrays (n_sections, channels): rows index sections for a cheap loop
        self._b0, self._b1, self._b2 = (np.ascontiguousarray(s[:, :, j].T) for j in range(3))
        self._a1, self._a2 = (np.ascontiguousarray(s[:, :, j].T) for j in (4, 5))
        self.channels = int(channels)
        self.sections = int(s.shape[1])
        self._z = np.zeros((self.sections, 2, self.channels))
        self._y = np.zeros(self.channels)
        self._scalar = self.channels * self.sections <= SCALAR_MAX
        self._views()

    def _views(self) -> None:
        # flat double views of the same memory (the arrays stay the filter's state, shared with
        # fastsim): a few channels step as Python floats, ~0.6 us instead of ~7 us of numpy
        # calls per sample for one channel and two sections, with the same operations
        self._flat = tuple(flat(a) for a in
                           (self._b0, self._b1, self._b2, self._a1, self._a2, self._z))

    def __getstate__(self) -> dict[str, Any]:
        # views are not copied or pickled: a copy gets views of its own arrays
        return {k: v for k, v in self.__dict__.items() if k != "_flat"}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._views()

    @property
    def scalar(self) -> bool:
        """True if :meth:`step_floats` is the cheaper form (few channels and sections)."""
        return self._scalar

    @property
    def arrays(self) -> SosArrays:
        """The coefficient and state arrays this filter steps with (shared, see
        :class:`SosArrays`)."""
        return SosArrays(self._b0, self._b1, self._b2, self._a1, self._a2, self._z)

    def coefficients(self) -> Array:
        """The normalised coefficients the filter runs, shape (channels, n_sections, 6), rows
        ``[b0 b1 b2 1 a1 a2]`` (a copy)."""
        s = np.empty((self.channels, self.sections, 6))
        for j, arr in enumerate((self._b0, self._b1, self._b2)):
            s[:, :, j] = arr.T
        s[:, :, 3] = 1.0
        s[:, :, 4] = self._a1.T
        s[:, :, 5] = self._a2.T
        return s

    def reset(self) -> None:
        """Zero every delay state."""
        self._z.fill(0.0)

    def get_state(self, out: Array | None = None) -> Array:
        """A copy of the delay states, shape (n_sections, 2, channels), written into ``out``
        when given (no allocation)."""
        if out is None:
            return self._z.copy()
        np.copyto(out, self._z)
        return out

    def set_state(self, state: ArrayLike) -> None:
        """Copy delay states in (shape as returned by :meth:`get_state`)."""
        np.copyto(self._z, np.asarray(state, dtype=np.float64))

    def prime(self, x: ArrayLike) -> None:
        """Set the delay states to the steady state of a constant input ``x`` (channels,), so
        a filter started on a running signal gives no start-up transient (a bumpless start).
        Channels whose filter has no steady state (a pole at z = 1) are left at zero."""
        u = np.asarray(x, dtype=np.float64)
        one = np.ones(self.sections)
        for c in range(self.channels):
            sos = np.column_stack([self._b0[:, c], self._b1[:, c], self._b2[:, c], one,
                                   self._a1[:, c], self._a2[:, c]])
            with np.errstate(all="ignore"):
                try:
                    zi = sos_steady_state(sos) * u[c]
                except (np.linalg.LinAlgError, ValueError):
                    continue
            if np.isfinite(zi).all():
                self._z[:, :, c] = zi

    def step(self, x: ArrayLike) -> Array:
        """Filter one sample per channel.

        Parameters
        ----------
        x : array_like, shape (channels,)

        Returns
        -------
        ndarray, shape (channels,)
            A new array (callers may keep it).
        """
        if self._scalar:
            return np.array(self.step_floats(np.asarray(x, dtype=np.float64).tolist()))
        u = np.asarray(x, dtype=np.float64)
        z = self._z
        for i in range(self.sections):
            z0, z1 = z[i, 0], z[i, 1]
            y = self._b0[i] * u + z0
            # same operation order as scipy's _sosfilt so results agree to the last bit
            z0[...] = self._b1[i] * u - self._a1[i] * y + z1
            z1[...] = self._b2[i] * u - self._a2[i] * y
            u = y
        return np.array(u, dtype=np.float64, copy=True)

    def step_floats(self, x: list[float]) -> list[float]:
        """:meth:`step` on Python floats (channels,), the same operations in the same order
        (so the same bits as the array form and as scipy's ``sosfilt``); the state is the
        filter's own array, advanced in place."""
        b0, b1, b2, a1, a2, z = self._flat
        ch, out = self.channels, []
        for c in range(ch):
            u = x[c]
            j, k = c, c
            for _ in range(self.sections):
                y = b0[j] * u + z[k]
                z[k] = b1[j] * u - a1[j] * y + z[k + ch]
                z[k + ch] = b2[j] * u - a2[j] * y
                u = y
                j += ch
                k += 2 * ch
            out.append(u)
        return out

    def run(self, x: ArrayLike) -> Array:
        """Filter a block, shape (K, channels) -> (K, channels), continuing the state."""
        xs = np.asarray(x, dtype=np.float64)
        out = np.empty_like(xs)
        for k in range(xs.shape[0]):
            out[k] = self.step(xs[k])
        return out


def sosfilt(sos: ArrayLike, x: ArrayLike, zi: ArrayLike) -> tuple[Array, Array]:
    """Filter a block through sections ``sos`` along axis 0 (``scipy.signal.sosfilt`` with
    ``axis=0``): the same operations in the same order, so the same bits.

    Parameters
    ----------
    sos : array_like, shape (n, 6)
        Sections ``[b0 b1 b2 1 a1 a2]`` (``a0`` must be 1).
    x : array_like, shape (K, channels)
        Samples, any unit.
    zi : array_like, shape (n, 2, channels)
        Delay states at the start (units of the output).

    Returns
    -------
    y : ndarray, shape (K, channels)
    zf : ndarray, shape (n, 2, channels)
        The delay states after the block.
    """
    s = np.asarray(sos, dtype=np.float64).reshape(-1, 6)
    if np.any(s[:, 3] != 1.0):
        raise ValueError("sosfilt: a0 of every section must be 1")
    xs = np.asarray(x, dtype=np.float64)
    zf = np.array(zi, dtype=np.float64, copy=True)
    y = np.empty_like(xs)
    rows = s.tolist()
    # section by section over the whole block, one channel at a time on Python floats: each
    # section sees the same input sequence as sample by sample, and a few channels of a
    # checkpoint block cost less than numpy's per-call overhead
    for c in range(xs.shape[1]):
        u = xs[:, c].tolist()
        for i, (b0, b1, b2, _, a1, a2) in enumerate(rows):
            z0, z1 = float(zf[i, 0, c]), float(zf[i, 1, c])
            out = []
            for v in u:
                w = b0 * v + z0
                z0 = b1 * v - a1 * w + z1
                z1 = b2 * v - a2 * w
                out.append(w)
            zf[i, 0, c], zf[i, 1, c] = z0, z1
            u = out
        y[:, c] = u
    return y, zf


def sos_state_space(sos: ArrayLike) -> tuple[Array, Array, Array, Array]:
    """The exact state-space form of one channel of :class:`SosFilter`.

    Parameters
    ----------
    sos : array_like, shape (n, 6)
        Sections ``[b0 b1 b2 a0 a1 a2]``.

    Returns
    -------
    a, b, c, d : ndarray, shapes (2n, 2n), (2n, 1), (1, 2n), (1, 1)
        ``z[k+1] = a z[k] + b u[k]``, ``y[k] = c z[k] + d u[k]`` with the state ordered as the
        filter's delays, section by section (``z[i, 0], z[i, 1]``), so a state vector read from
        :meth:`SosFilter.get_state` evolves identically.
    """
    s = np.asarray(sos, dtype=np.float64).reshape(-1, 6)
    s = s / s[:, 3:4]
    n = 2 * s.shape[0]
    a = np.zeros((n, n))
    b = np.zeros((n, 1))
    # the running input of section i as a map of the states (cu) and the filter input (du)
    cu = np.zeros((1, n))
    du = np.ones((1, 1))
    for i, (b0, b1, b2, _, a1, a2) in enumerate(s):
        j = 2 * i
        # y_i = b0 u_i + z0; z0' = b1 u_i - a1 y_i + z1; z1' = b2 u_i - a2 y_i
        cy = b0 * cu
        cy[0, j] += 1.0
        dy = b0 * du
        a[j] = b1 * cu[0] - a1 * cy[0]
        a[j, j + 1] += 1.0
        b[j] = b1 * du[0] - a1 * dy[0]
        a[j + 1] = b2 * cu[0] - a2 * cy[0]
        b[j + 1] = b2 * du[0] - a2 * dy[0]
        cu, du = cy, dy
    return a, b, cu, du


__all__ = ["SCALAR_MAX", "BlockFilter", "SosArrays", "SosFilter", "flat", "sos_state_space",
           "sosfilt"]
