"""Routh-Hurwitz array and the characteristic polynomial of the vertical N-stage cascade."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.lti import Array
from dcsms_ros.errors import ConfigError

#: Relative size of the epsilon that replaces a zero first-column element.
ROUTH_EPS = 1e-9


@dataclass(frozen=True)
class RouthResult:
    """Routh array (rows s^n .. s^0, zero-padded, shape (n+1, ceil((n+1)/2))), its first column,
    the number of sign changes there (= right-half-plane roots), and asymptotic stability (no
    sign change, no zero row, no epsilon substitution: those mean roots on the imaginary axis)."""

    array: Array
    first_column: Array
    sign_changes: int
    stable: bool


def routh(coeffs: ArrayLike) -> RouthResult:
    """Routh-Hurwitz test of a real polynomial, coefficients highest power first.

    A zero first element in an otherwise non-zero row is replaced by a small positive epsilon
    (``ROUTH_EPS`` times the largest coefficient); a row of zeros is replaced by the derivative
    of the auxiliary polynomial formed from the row above.
    """
    c = np.trim_zeros(np.asarray(coeffs, dtype=float), "f")
    if c.size == 0:
        raise ValueError("routh: the zero polynomial has no Routh array")
    if c[0] < 0:
        c = -c
    n = c.size - 1
    width = n // 2 + 1
    arr = np.zeros((n + 1, width))
    arr[0, : c[0::2].size] = c[0::2]
    if n >= 1:
        arr[1, : c[1::2].size] = c[1::2]
    eps = ROUTH_EPS * float(np.max(np.abs(c)))
    marginal = False
    for r in range(1, n + 1):
        if r >= 2:
            p, q = arr[r - 2], arr[r - 1]
            for j in range(width - 1):
                arr[r, j] = (q[0] * p[j + 1] - p[0] * q[j + 1]) / q[0]
        if not np.any(np.abs(arr[r]) > 1e-12 * float(np.max(np.abs(arr[r - 1])))):
            # row of zeros: derivative of the auxiliary polynomial of degree n - r + 1
            deg = n - r + 1
            powers = deg - 2 * np.arange(width)
            arr[r] = np.where(powers > 0, arr[r - 1] * powers, 0.0)
            marginal = True
        if arr[r, 0] == 0.0 or abs(arr[r, 0]) <= 1e-12 * float(np.max(np.abs(arr[r]))):
            arr[r, 0] = eps
            marginal = True
    first = arr[:, 0].copy()
    changes = int(np.count_nonzero(np.diff(np.sign(first)) != 0))
    return RouthResult(arr, first, changes, changes == 0 and not marginal)


def characteristic_polynomial(cfg: SystemConfig) -> Array:
    """``det(M s^2 + C s + K)`` of the vertical N-stage chain, coefficients highest power
    first (for N = 2 the polynomial of NOTES.md); units kg^N s^2N ... .

    Uses the continuant recurrence of the tridiagonal matrix: ``f_i = d_i f_{i-1} -
    (c_i s + k_i)^2 f_{i-2}`` with ``d_i = m_i s^2 + (c_i + c_{i+1}) s + k_i + k_{i+1}``.
    """
    if cfg.plant.dof != 1:
        raise ConfigError(f"{cfg.source}: characteristic_polynomial needs the 1dof model")
    st = cfg.plant.stages
    n = len(st)
    f_prev, f = np.ones(1), np.ones(1)
    for i in range(n):
        c_up = st[i + 1].damping if i + 1 < n else 0.0
        k_up = st[i + 1].stiffness if i + 1 < n else 0.0
        d = np.array([st[i].mass, st[i].damping + c_up, st[i].stiffness + k_up])
        coupling = np.polymul([st[i].damping, st[i].stiffness], [st[i].damping, st[i].stiffness])
        nxt = np.polymul(d, f) if i == 0 else np.polysub(np.polymul(d, f),
                                                         np.polymul(coupling, f_prev))
        f_prev, f = f, nxt
    return np.asarray(f, dtype=float)
