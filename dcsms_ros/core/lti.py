"""Small LTI helpers without slycot: SISO state space -> transfer function, frequency response.

python-control's ``ss2tf`` (without slycot) forms the numerator as ``poly(A - BC) - poly(A)``,
which loses the high-frequency roll-off of a cascade to cancellation. Here the poles are the
eigenvalues of ``A``, the zeros the finite generalised eigenvalues of the Rosenbrock pencil, the
modes that cancel (uncontrollable or unobservable) are dropped, and the gain is fitted to the
exact state-space response, so spurious large zeros cannot distort the band of interest.
"""

from __future__ import annotations

import math
from typing import Any

import control as ct
import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.filterdesign import Rational

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

#: Relative distance under which a zero and a pole are taken to be the same mode.
CANCEL_TOL = 1e-6


def as_tf(h: Any) -> Any:
    """A scalar, :class:`.filterdesign.Rational` or LTI system as a python-control
    TransferFunction (same coefficients, same units)."""
    if isinstance(h, ct.TransferFunction):
        return h
    if isinstance(h, Rational):
        return ct.tf(h.num, h.den)
    if isinstance(h, ct.StateSpace):
        return ss_to_tf(h.A, h.B, h.C, h.D)
    return ct.tf([float(h)], [1.0])


def num_den(h: Any) -> tuple[Array, Array]:
    """Numerator and denominator coefficient arrays (highest power first) of a SISO H."""
    t = as_tf(h)
    return (np.asarray(t.num[0][0], dtype=float).copy(),
            np.asarray(t.den[0][0], dtype=float).copy())


def ss_response(a: Array, b: Array, c: Array, d: float, s: CArray) -> CArray:
    """``c (sI - a)^-1 b + d`` of a SISO system at complex points ``s`` (any shape)."""
    n = a.shape[0]
    flat = np.ravel(s)
    out = np.empty(flat.shape, dtype=complex)
    eye = np.eye(n)
    for k, sk in enumerate(flat):
        out[k] = (c @ np.linalg.solve(sk * eye - a, b)).item() + d if n else d
    return out.reshape(np.shape(s))


def _cancel(zeros: CArray, poles: CArray) -> tuple[CArray, CArray]:
    keep_p = list(poles)
    keep_z = []
    for z in zeros:
        if keep_p:
            dist = np.abs(np.asarray(keep_p) - z)
            j = int(np.argmin(dist))
            if dist[j] <= CANCEL_TOL * max(1.0, abs(z)):
                keep_p.pop(j)
                continue
        keep_z.append(z)
    return np.asarray(keep_z, dtype=complex), np.asarray(keep_p, dtype=complex)


def _real_poly(roots: CArray) -> Array:
    # conjugate pairs come out with tiny imaginary residue: keep the real part only
    return np.real(np.poly(roots)) if roots.size else np.ones(1)


def ss_to_tf(a: ArrayLike, b: ArrayLike, c: ArrayLike, d: ArrayLike = 0.0) -> Any:
    """Minimal SISO transfer function of ``(a, b, c, d)``.

    Parameters
    ----------
    a, b, c, d : array_like
        Shapes (n, n), (n, 1), (1, n), scalar or (1, 1); continuous time.

    Returns
    -------
    control.TransferFunction
        Same input/output units as the state space.
    """
    a_ = np.atleast_2d(np.asarray(a, dtype=float))
    b_ = np.asarray(b, dtype=float).reshape(-1, 1)
    c_ = np.asarray(c, dtype=float).reshape(1, -1)
    d_ = float(np.asarray(d, dtype=float).reshape(-1)[0]) if np.size(d) else 0.0
    n = b_.shape[0]
    if n == 0:
        return ct.tf([d_], [1.0])
    # diagonal balancing of the whole system matrix: tf2ss realisations of the filters are
    # scaled over ~9 decades, which otherwise costs ~5 digits in the zeros
    pencil_a, _ = scipy.linalg.matrix_balance(np.block([[a_, b_], [c_, np.array([[d_]])]]),
                                              permute=False)
    a_, b_, c_ = pencil_a[:n, :n], pencil_a[:n, n:], pencil_a[n:, :n]
    poles = scipy.linalg.eigvals(a_)
    pencil_b = np.zeros((n + 1, n + 1))
    pencil_b[:n, :n] = np.eye(n)
    ab = scipy.linalg.eigvals(pencil_a, pencil_b, homogeneous_eigvals=True)
    alpha, beta = ab[0], ab[1]
    scale = max(1.0, float(np.max(np.abs(poles))))
    finite = np.abs(beta) * 1e8 * scale > np.abs(alpha)
    zeros = alpha[finite] / beta[finite]
    zeros[np.abs(zeros) < 1e-10 * scale] = 0.0  # a numerically tiny zero is a zero at s = 0
    zeros, poles = _cancel(zeros, poles)
    if zeros.size > poles.size - (0 if d_ else 1):
        # numerically "finite" infinite eigenvalues: drop the largest
        keep = poles.size - (0 if d_ else 1)
        zeros = zeros[np.argsort(np.abs(zeros))[:max(keep, 0)]]
    num, den = _real_poly(zeros), _real_poly(poles)
    # gain by least squares against the exact response at frequencies spread over the poles
    w = np.geomspace(max(1e-2, 0.1 * float(np.min(np.abs(poles)))), 10.0 * scale, 25)
    s = np.asarray(1j * w, dtype=np.complex128)
    exact = ss_response(a_, b_, c_, d_, s)
    shape = np.polyval(num, s) / np.polyval(den, s)
    k = float(np.real(np.vdot(shape, exact) / np.vdot(shape, shape)))
    return ct.tf(k * num, den)


def freq_response(sys: Any, f_hz: ArrayLike) -> CArray:
    """Complex frequency response of a SISO python-control system at ``f_hz`` (Hz), shape of
    ``f_hz`` (units: the system's output per input)."""
    f = np.asarray(f_hz, dtype=float)
    s = np.asarray(2j * math.pi * f, dtype=np.complex128)
    if isinstance(sys, ct.StateSpace):
        return ss_response(np.asarray(sys.A), np.asarray(sys.B), np.asarray(sys.C),
                           float(np.asarray(sys.D).reshape(-1)[0]), s)
    num, den = num_den(sys)
    return np.asarray(np.polyval(num, s) / np.polyval(den, s), dtype=complex)
