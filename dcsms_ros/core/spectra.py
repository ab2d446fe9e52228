"""Predicted spectra and RMS of the running loop under the configured disturbances.

The disturbance sources of :class:`.Disturbances` and the geophone self-noise of
:class:`.GeophoneArray` are independent unit-variance white sequences through known filters:
ground velocity and table forces are band-passed (their Butterworth sections, scaled to the
configured RMS), the self-noise is white with ``noise_asd * sqrt(fs/2)`` m/s per sample.
:func:`shaped` puts those filters in front of a :class:`.LoopModel`, so its inputs are the white
sequences themselves. Then the one-sided PSD of output i is ``(2/fs) sum_j |H_ij|^2`` and its
variance the diagonal of ``C P C' + D D'`` with ``P = A P A' + B B'`` (discrete Lyapunov).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.disturbance import BandNoise, Disturbances
from dcsms_ros.core.loop_model import LoopModel, freq_response
from dcsms_ros.core.sosfilter import sos_state_space

Array = NDArray[np.float64]


def _source(noise: BandNoise | None, channels: int) -> tuple[Array, ...]:
    """(a, b, c, d) from unit white noise per channel to the source's output."""
    if noise is None:
        z = np.zeros((0, 0))
        return z, np.zeros((0, channels)), np.zeros((channels, 0)), np.zeros((channels,
                                                                              channels))
    scale = noise.scale
    if noise.sos is None:
        return (np.zeros((0, 0)), np.zeros((0, channels)), np.zeros((channels, 0)),
                np.diag(scale))
    fa, fb, fc, fd = sos_state_space(noise.sos)
    eye = np.eye(channels)
    return tuple(np.asarray(m, dtype=np.float64) for m in (
        np.kron(eye, fa), np.kron(eye, fb), np.kron(np.diag(scale), fc),
        np.kron(np.diag(scale), fd)))


def shaped(cfg: SystemConfig, model: LoopModel) -> LoopModel:
    """``model`` driven by the configured disturbances from independent unit-variance white
    sequences.

    Returns
    -------
    LoopModel
        Inputs ``ground`` (driven axes: 1 in 1dof, 3 in 6dof), ``table`` (N x that, stage by
        stage) and ``noise`` (one per geophone channel), each unit-variance white; the outputs
        and the states of ``model`` come first, then the shaping filters' states.
    """
    dist = Disturbances(cfg, seed=0, warm=False)
    nt = dist.translations
    n, dof = cfg.plant.num_stages, cfg.plant.dof
    ga, gb, gc, gd = _source(dist.ground_noise, nt)
    fa, fb, fc, fd = _source(dist.force_noise, n * nt)
    n_ch = model.inputs["noise"].stop - model.inputs["noise"].start
    noise_std = float(cfg.sensors.noise_asd) * np.sqrt(cfg.plant.rate_hz / 2.0)
    # where each white source enters the loop's inputs
    put_g = np.zeros((model.b.shape[1], nt))
    put_g[model.inputs["ground"].start + np.arange(nt), np.arange(nt)] = 1.0
    put_f = np.zeros((model.b.shape[1], n * nt))
    for i in range(n):
        rows = model.inputs["table"].start + i * dof + np.arange(nt)
        put_f[rows, i * nt + np.arange(nt)] = 1.0
    bg, bf = model.b @ put_g, model.b @ put_f
    dg, df = model.d @ put_g, model.d @ put_f
    nx, ng, nf = model.nstates, ga.shape[0], fa.shape[0]
    a = np.zeros((nx + ng + nf, nx + ng + nf))
    a[:nx, :nx] = model.a
    a[:nx, nx:nx + ng] = bg @ gc
    a[:nx, nx + ng:] = bf @ fc
    a[nx:nx + ng, nx:nx + ng] = ga
    a[nx + ng:, nx + ng:] = fa
    bn = model.b[:, model.inputs["noise"]] * noise_std
    b = np.zeros((a.shape[0], nt + n * nt + n_ch))
    b[:nx, :nt] = bg @ gd
    b[:nx, nt:nt + n * nt] = bf @ fd
    b[:nx, nt + n * nt:] = bn
    b[nx:nx + ng, :nt] = gb
    b[nx + ng:, nt:nt + n * nt] = fb
    c = np.hstack([model.c, dg @ gc, df @ fc])
    d = np.hstack([dg @ gd, df @ fd, model.d[:, model.inputs["noise"]] * noise_std])
    inputs = {"ground": slice(0, nt), "table": slice(nt, nt + n * nt),
              "noise": slice(nt + n * nt, nt + n * nt + n_ch)}
    return LoopModel(a, b, c, d, model.dt, inputs, dict(model.outputs), model.mode,
                     model.breaks)


def psd(model: LoopModel, f_hz: Array, outputs: slice | None = None) -> Array:
    """One-sided PSD (output unit^2/Hz) of each output of a :func:`shaped` model at ``f_hz``.

    Returns
    -------
    ndarray, shape (F, n_outputs)
    """
    sub = model if outputs is None else model.select(slice(0, model.b.shape[1]), outputs)
    h = freq_response(sub, f_hz)
    return np.asarray((2.0 * model.dt) * np.sum(np.abs(h) ** 2, axis=2), dtype=np.float64)


def covariance(model: LoopModel, outputs: slice | None = None) -> Array:
    """Stationary covariance of the outputs of a :func:`shaped` model (inf when unstable).

    Returns
    -------
    ndarray, shape (n_outputs, n_outputs)
    """
    c = model.c if outputs is None else model.c[outputs]
    d = model.d if outputs is None else model.d[outputs]
    if np.max(np.abs(np.linalg.eigvals(model.a)), initial=0.0) >= 1.0:
        return np.full((c.shape[0], c.shape[0]), np.inf)
    p = scipy.linalg.solve_discrete_lyapunov(model.a, model.b @ model.b.T)
    return np.asarray(c @ p @ c.T + d @ d.T, dtype=np.float64)


def rms(model: LoopModel, outputs: slice | None = None) -> Array:
    """Stationary RMS of each output of a :func:`shaped` model (output units)."""
    return np.sqrt(np.maximum(np.diag(covariance(model, outputs)), 0.0))


__all__ = ["covariance", "psd", "rms", "shaped"]
