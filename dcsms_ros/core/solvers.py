"""Two small numerical solvers for the stability margins (:mod:`.margins`): a bracketed root
(Brent's method) and a derivative-free minimum (Nelder-Mead).

Why not ``scipy.optimize``: every process that holds the stability guard (each controller,
``mode_switch``) imports the margins, and ``scipy.optimize`` adds ~0.35 s of CPU to each start
(its linear programming, FFT and special-function modules come with it): ~1.4 s of CPU on two
cores for a one-process-per-node graph whose start is bound by its imports. The margins need
one root between two grid points and a minimum over at most a few variables, which these plain
versions give (``test/core/test_solvers.py`` compares them with scipy's).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

#: Relative tolerance of :func:`brent_root` on top of ``xtol`` (a few ulps, as scipy's).
RTOL = 4.0 * np.finfo(float).eps


def brent_root(fun: Callable[[float], float], a: float, b: float, xtol: float,
               maxiter: int = 100) -> float:
    """A root of ``fun`` in ``[a, b]``, where ``fun(a)`` and ``fun(b)`` differ in sign, to
    within ``xtol + RTOL |x|`` (Brent's method: inverse quadratic or secant steps while they
    shrink the bracket fast enough, bisection otherwise).

    Parameters
    ----------
    fun : callable
        ``fun(x) -> float``.
    a, b : float
        The bracket.
    xtol : float
        Absolute tolerance on the root (the unit of ``a``).
    maxiter : int
        Evaluations at most.

    Raises
    ------
    ValueError
        ``fun(a)`` and ``fun(b)`` have the same sign (no root bracketed).
    RuntimeError
        No convergence within ``maxiter`` evaluations.
    """
    fa, fb = float(fun(a)), float(fun(b))
    if fa == 0.0:
        return a
    if fb == 0.0:
        return b
    if (fa > 0) == (fb > 0):
        raise ValueError(f"no sign change between {a!r} and {b!r}: f = {fa!r}, {fb!r}")
    c, fc = a, fa
    d = e = b - a
    for _ in range(maxiter):
        if (fb > 0) == (fc > 0):  # keep the root between b and c
            c, fc = a, fa
            d = e = b - a
        if abs(fc) < abs(fb):  # b is the best estimate
            a, b, c = b, c, b
            fa, fb, fc = fb, fc, fb
        tol = 2.0 * RTOL * abs(b) + 0.5 * xtol
        m = 0.5 * (c - b)
        if abs(m) <= tol or fb == 0.0:
            return b
        if abs(e) >= tol and abs(fa) > abs(fb):
            s = fb / fa
            if a == c:  # secant
                p, q = 2.0 * m * s, 1.0 - s
            else:  # inverse quadratic through a, b, c
                qa, r = fa / fc, fb / fc
                p = s * (2.0 * m * qa * (qa - r) - (b - a) * (r - 1.0))
                q = (qa - 1.0) * (r - 1.0) * (s - 1.0)
            if p > 0:
                q = -q
            else:
                p = -p
            if 2.0 * p < min(3.0 * m * q - abs(tol * q), abs(e * q)):
                e, d = d, p / q  # the step is accepted
            else:
                d = e = m  # too slow: bisect
        else:
            d = e = m
        a, fa = b, fb
        b += d if abs(d) > tol else math.copysign(tol, m)
        fb = float(fun(b))
    raise RuntimeError(f"no root to {xtol!r} in {maxiter} evaluations")


def nelder_mead(fun: Callable[[Array], float], x0: ArrayLike, xatol: float, fatol: float,
                maxiter: int) -> tuple[Array, float]:
    """A local minimum of ``fun`` from ``x0`` by the Nelder-Mead simplex (reflection 1,
    expansion 2, contraction 0.5, shrink 0.5; the first simplex steps each coordinate by 5 %,
    or 0.00025 where it is zero).

    Parameters
    ----------
    fun : callable
        ``fun(x) -> float``, ``x`` of shape (n,).
    x0 : array_like, shape (n,)
        The start.
    xatol, fatol : float
        Stop once every vertex is within ``xatol`` of the best in each coordinate and within
        ``fatol`` of its value.
    maxiter : int
        Iterations at most (the best vertex so far is returned then).

    Returns
    -------
    x : ndarray, shape (n,)
    value : float
        ``fun(x)``.
    """
    x = np.asarray(x0, dtype=float).ravel()
    n = x.size
    sim = np.empty((n + 1, n))
    sim[0] = x
    for k in range(n):
        y = x.copy()
        y[k] = 1.05 * y[k] if y[k] != 0 else 0.00025
        sim[k + 1] = y
    fs = np.array([fun(v) for v in sim], dtype=float)
    order = np.argsort(fs, kind="stable")
    sim, fs = sim[order], fs[order]
    for _ in range(maxiter):
        if np.max(np.abs(sim[1:] - sim[0])) <= xatol and np.max(np.abs(fs[0] - fs[1:])) <= fatol:
            break
        centre = sim[:-1].mean(axis=0)
        worst = sim[-1]
        xr = 2.0 * centre - worst
        fr = fun(xr)
        if fr < fs[0]:
            xe = 3.0 * centre - 2.0 * worst
            fe = fun(xe)
            sim[-1], fs[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < fs[-2]:
            sim[-1], fs[-1] = xr, fr
        else:
            if fr < fs[-1]:  # outside the simplex: contract towards the reflection
                xc = 1.5 * centre - 0.5 * worst
                fc = fun(xc)
                accept = fc <= fr
            else:  # contract inside
                xc = 0.5 * centre + 0.5 * worst
                fc = fun(xc)
                accept = fc < fs[-1]
            if accept:
                sim[-1], fs[-1] = xc, fc
            else:  # shrink towards the best vertex
                sim[1:] = sim[0] + 0.5 * (sim[1:] - sim[0])
                fs[1:] = [fun(v) for v in sim[1:]]
        order = np.argsort(fs, kind="stable")
        sim, fs = sim[order], fs[order]
    return sim[0].copy(), float(fs[0])


__all__ = ["RTOL", "brent_root", "nelder_mead"]
