"""Model frequency responses as the analysis measures them.

The discrete loop model (:func:`dcsms_ros.core.loop_model.loop_model`, the loop exactly as the
batch engine runs it) gives the responses the analysis estimates from a bag:

* *mobility*: excitation wrench on stage s, axis a -> decoupled velocity of each stage on axis a
  ((m/s)/N; the ``excite`` input: added to the controllers' wrench before allocation);
* *transmissibility*: decoupled stage velocity over decoupled ground velocity on axis a, both
  driven by the ground (-; the ratio of two ``velocity`` outputs of the ``ground`` input).

A bag holding only ``/dcsms/truth/*`` is compared with the true velocities (``stage`` outputs,
the ground input itself) instead.

A Welch H1 estimate with a Hann window of ``nperseg`` samples does not see H(f) itself but H
averaged over the window's spectral kernel ``|W(f)|^2`` (the expectation of every windowed cross
spectrum is the true one convolved with it). Near a lightly damped resonance whose half-power
width is about one bin (Table 1: 0.14 Hz at 3.77 Hz against 0.12 Hz bins) that smooths the peak
by several dB. :func:`as_estimated` applies the same kernel to the model, so model and estimate
are compared (and fitted) like with like; the input spectrum is taken as smooth across the
kernel's few bins, or given.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence

import numpy as np
import scipy.linalg
from numpy.typing import NDArray
from scipy import signal

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.loop_model import LoopModel, Response, loop_model
from dcsms_ros.core.modes import Mode

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

#: Kernel points per Welch bin and half-width of the kernel in bins (Hann: |W|^2 falls below
#: 1e-6 of its peak 4 bins out).
OVERSAMPLE = 8
KERNEL_BINS = 4
#: The modal (eigenvector) evaluation is used when it agrees with the Schur one to this.
MODAL_RTOL = 1e-7


class FastResponse:
    """``c (zI - a)^-1 b + d`` at many frequencies: modal form ``a = V L V^-1`` evaluated for
    all frequencies at once, checked at a few frequencies against a direct solve; when they
    differ (a near-defective matrix) the Schur solve of
    :class:`~dcsms_ros.core.loop_model.Response` is used instead.

    Parameters
    ----------
    model : LoopModel
        A sub-system (``model.select``) or a whole loop.
    """

    def __init__(self, model: LoopModel) -> None:
        self._model = model
        self._dt = model.dt
        self._d = model.d
        self._modal: tuple[CArray, CArray, CArray] | None = None
        try:
            lam, v = scipy.linalg.eig(model.a)
            cb = model.c @ v
            vb = np.linalg.solve(v, model.b.astype(np.complex128))
            self._modal = (lam, cb, vb)
        except (np.linalg.LinAlgError, ValueError):
            self._modal = None
        if self._modal is not None:
            probe = np.array([0.7, 3.7, 9.4, 37.0, 150.0])
            probe = probe[probe < 0.5 / self._dt]
            eye = np.eye(model.a.shape[0])
            exact = np.array([model.c @ np.linalg.solve(np.exp(2j * np.pi * f * self._dt) * eye
                                                        - model.a, model.b) + model.d
                              for f in probe])
            got = self._eval_modal(probe)
            scale = np.max(np.abs(exact)) or 1.0
            if np.max(np.abs(got - exact)) > MODAL_RTOL * scale:
                self._modal = None
        self._schur: Response | None = None if self._modal is not None else Response(model)

    def _eval_modal(self, f: Array, rows: Sequence[int] | None = None,
                    cols: Sequence[int] | None = None) -> CArray:
        assert self._modal is not None
        lam, cb, vb = self._modal
        d = self._d
        if rows is not None:
            cb, d = cb[list(rows)], d[list(rows)]
        if cols is not None:
            vb, d = vb[:, list(cols)], d[:, list(cols)]
        z = np.exp(2j * np.pi * f * self._dt)
        inv = 1.0 / (z[:, None] - lam[None, :])
        return np.asarray(np.einsum("oi,fi,ij->foj", cb, inv, vb) + d, dtype=np.complex128)

    def __call__(self, f_hz: Sequence[float] | Array, rows: Sequence[int] | None = None,
                 cols: Sequence[int] | None = None) -> CArray:
        """Shape (F, n_outputs, n_inputs), or only the outputs ``rows`` and inputs ``cols``."""
        f = np.asarray(f_hz, dtype=np.float64).ravel()
        if self._modal is not None:
            return self._eval_modal(f, rows, cols)
        assert self._schur is not None
        h = self._schur(f)
        h = h if rows is None else h[:, list(rows)]
        return h if cols is None else h[:, :, list(cols)]


def _axis_index(dof: int, axis: str) -> int:
    return 0 if dof == 1 else "xyz".index(axis)


class LoopFrf:
    """Mobility and transmissibility of one mode's loop (module docstring).

    Parameters
    ----------
    cfg : SystemConfig
        The configuration the controllers and the decoupling ran with (a bag's
        ``/dcsms/config``).
    mode : Mode
    plant : SystemConfig, optional
        The physical plant when it differs from ``cfg`` (candidate parameters of a fit).
    truth : bool
        Compare with true velocities (a bag without ``/dcsms/velocity/*``).
    gain : float
        Scale of every measured velocity (a geophone sensitivity error; Passive only, where no
        loop closes through the sensors).
    """

    def __init__(self, cfg: SystemConfig, mode: Mode, plant: SystemConfig | None = None,
                 truth: bool = False, gain: float = 1.0) -> None:
        self.cfg = cfg
        self.dof = cfg.plant.dof
        self.n = cfg.plant.num_stages
        self.truth = truth
        self.gain = gain
        self.model = loop_model(cfg, mode, plant=plant)
        # one modal decomposition serves every response: inputs ground then excite
        g, e = self.model.inputs["ground"], self.model.inputs["excite"]
        self._cols = {"ground": 0, "excite": g.stop - g.start}
        out = self.model.outputs["stage" if self.truth else "velocity"]
        self._resp = FastResponse(self.model.select([*range(g.start, g.stop),
                                                     *range(e.start, e.stop)], out))

    def _rows(self, axis: str, stages: Sequence[int]) -> list[int]:
        """Output rows of ``stages`` (1-based; 0 = ground, velocity outputs only) on ``axis``."""
        j = _axis_index(self.dof, axis)
        base = 1 if self.truth else 0  # the stage outputs have no ground block
        return [(s - base) * self.dof + j for s in stages]

    def mobility(self, f_hz: Array, stage: int, axis: str, stages: Sequence[int]) -> CArray:
        """Excitation on ``stage`` (1-based) along ``axis`` -> velocity of each of ``stages``
        along ``axis``, (m/s)/N, shape (F, len(stages))."""
        col = self._cols["excite"] + (stage - 1) * self.dof + _axis_index(self.dof, axis)
        h = self._resp(f_hz, self._rows(axis, stages), [col])[:, :, 0]
        return np.asarray(self.gain * h, dtype=np.complex128)

    def transmissibility(self, f_hz: Array, axis: str, stages: Sequence[int]) -> CArray:
        """Velocity of each of ``stages`` over the ground velocity along ``axis`` for the ground
        input, shape (F, len(stages))."""
        col = self._cols["ground"] + _axis_index(self.dof, axis)
        rows = self._rows(axis, stages) + ([] if self.truth else self._rows(axis, [0]))
        h = self._resp(f_hz, rows, [col])[:, :, 0]
        num = h[:, :len(stages)]
        if self.truth:
            return np.asarray(num, dtype=np.complex128)
        den = h[:, len(stages):]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(num / den, dtype=np.complex128)


@functools.lru_cache(maxsize=16)
def window_kernel(nperseg: int, oversample: int = OVERSAMPLE,
                  half_bins: int = KERNEL_BINS) -> Array:
    """The Hann window's spectral kernel ``|W|^2`` sampled every ``1/oversample`` bin over
    +-``half_bins`` bins, normalised to sum 1; shape (2 * half_bins * oversample + 1,)
    (read-only: cached)."""
    w = signal.get_window("hann", nperseg)
    spec = np.abs(np.fft.fft(w, nperseg * oversample)) ** 2
    m = half_bins * oversample
    k = np.concatenate([spec[-m:], spec[:m + 1]])
    out = np.asarray(k / np.sum(k), dtype=np.float64)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=64)
def _fine_grid(nperseg: int, fs: float, bins: bytes) -> tuple[Array, NDArray[np.bool_],
                                                               NDArray[np.intp]]:
    """The fine frequencies under the kernels of the bins ``bins`` (float64 bytes), which of
    them are negative (mirrored) and, per bin and kernel point, the index into them."""
    f_bins = np.frombuffer(bins, dtype=np.float64)
    df = fs / nperseg
    n = window_kernel(nperseg).size
    k = np.rint(f_bins / df).astype(np.int64)
    fine_idx = k[:, None] * OVERSAMPLE + np.arange(n)[None, :] - (n - 1) // 2
    uniq, inv = np.unique(fine_idx, return_inverse=True)
    return np.abs(uniq * (df / OVERSAMPLE)), uniq < 0, inv.reshape(fine_idx.shape)


def as_estimated(response: Callable[[Array], CArray], f_bins: Array, fs: float,
                 nperseg: int, sxx: Array | None = None) -> CArray:
    """A model response as a Welch H1 estimate on bins ``f_bins`` sees it (module docstring).

    Parameters
    ----------
    response : callable
        ``response(f_hz (M,)) -> (M, ...)`` complex, the model.
    f_bins : ndarray, shape (F,)
        Welch bin frequencies (Hz), multiples of ``fs / nperseg`` (any subset, any order).
    fs : float
        Sample rate, Hz.
    nperseg : int
        Welch segment length, samples.
    sxx : ndarray, shape (F,), optional
        The input's auto-spectrum on ``f_bins`` (any unit), interpolated across the kernel as a
        weight; default: flat.

    Returns
    -------
    ndarray of complex, shape (F, ...)
    """
    f_bins = np.ascontiguousarray(f_bins, dtype=np.float64)
    df = fs / nperseg
    kern = window_kernel(nperseg)
    offsets = (np.arange(kern.size) - (kern.size - 1) // 2) * (df / OVERSAMPLE)
    # one fine grid serves every bin: bins are multiples of df, offsets of df / OVERSAMPLE
    f_fine, neg, idx = _fine_grid(nperseg, float(fs), f_bins.tobytes())
    h = response(f_fine)
    h[neg] = np.conj(h[neg])  # H(-f) = conj(H(f)) of a real system
    hk = h[idx]  # (F, K, ...)
    weight = np.broadcast_to(kern, idx.shape)
    if sxx is not None:
        order = np.argsort(f_bins)
        s = np.interp((f_bins[:, None] + offsets[None, :]).ravel(), f_bins[order],
                      np.asarray(sxx, dtype=np.float64)[order]).reshape(idx.shape)
        weight = weight * np.maximum(s, 0.0)
    extra = (slice(None), slice(None)) + (None,) * (hk.ndim - 2)
    num = np.sum(hk * weight[extra], axis=1)
    den = np.sum(weight, axis=1)[(slice(None),) + (None,) * (hk.ndim - 2)]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(num / den, dtype=np.complex128)


__all__ = ["FastResponse", "LoopFrf", "as_estimated", "window_kernel"]
