"""Filter design on numpy alone: rational transfer functions, Butterworth prototypes, the
bilinear transform and second-order sections.

The nodes build every filter they run from here, so starting one imports neither
python-control nor ``scipy.signal`` (about 0.8 s of CPU per process). The steps are those of
``scipy.signal`` (``butter``, ``tf2zpk``, ``bilinear_zpk``, ``zpk2sos`` with its default
"nearest" pairing, ``sosfilt_zi``) computed with the same numpy operations in the same order,
so the sections agree with scipy's to the last bit on the filters the presets build
(``test/core/test_filterdesign.py`` checks them against scipy). Analysis wraps a
:class:`Rational` into python-control where it needs that library (:mod:`.lti`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

#: Relative size under which an imaginary part is rounding (a real root), as scipy takes it.
REAL_TOL = 100.0 * float(np.finfo(np.float64).eps)

#: Leading numerator coefficients at most this large (after dividing by the denominator's
#: leading one) are dropped before the roots are taken, as ``scipy.signal.normalize`` does.
LEADING_ZERO = 1e-14


@dataclass(frozen=True, eq=False)  # arrays: no elementwise == to misread as one bool
class Rational:
    """A SISO transfer function ``num(s) / den(s)``, coefficients highest power first.

    Products multiply the polynomials (``numpy.polymul``), as python-control's do, so a
    cascade built here has the coefficients the same cascade of ``control.tf`` has.

    Attributes
    ----------
    num, den : ndarray, shape (m,), (n,)
        Numerator and denominator coefficients; the units are those of the system
        (output per input), ``s`` in rad/s.
    """

    num: Array
    den: Array

    @classmethod
    def of(cls, num: ArrayLike, den: ArrayLike) -> Rational:
        """From coefficient sequences; leading zeros are dropped (an all-zero numerator is
        ``[0.0]``)."""
        return cls(_trim(num), _trim(den))

    def __mul__(self, other: Rational | float) -> Rational:
        if isinstance(other, Rational):
            return Rational.of(np.polymul(self.num, other.num), np.polymul(self.den, other.den))
        return Rational.of(np.polymul([float(other)], self.num), self.den)

    def __rmul__(self, other: float) -> Rational:
        return self * other

    def is_zero(self) -> bool:
        """True when the numerator is identically 0."""
        return not np.any(self.num)

    def response(self, f_hz: ArrayLike) -> CArray:
        """Complex response at frequencies ``f_hz`` (Hz), shape of ``f_hz``."""
        s = 2j * math.pi * np.asarray(f_hz, dtype=np.float64)
        return np.asarray(np.polyval(self.num, s) / np.polyval(self.den, s), dtype=complex)


def _trim(c: ArrayLike) -> Array:
    a = np.trim_zeros(np.atleast_1d(np.asarray(c, dtype=np.float64)), "f")
    # adding 0.0 makes every zero +0.0, as python-control's sum of products leaves them
    return a + 0.0 if a.size else np.zeros(1)


def unity() -> Rational:
    """The identity 1."""
    return Rational.of([1.0], [1.0])


def poly(roots: ArrayLike) -> NDArray[np.generic]:
    """Monic polynomial with the given roots (highest power first); real when the roots are
    real or come in exact conjugate pairs, else complex."""
    r = np.atleast_1d(np.asarray(roots))
    if r.size == 0:
        return np.ones(1)
    out = np.ones(1, dtype=r.dtype)
    for root in r:
        out = np.convolve(out, np.array([1.0, -root], dtype=r.dtype))
    if np.iscomplexobj(out):
        im = np.imag(r.astype(np.complex128))
        if np.all(np.sort(im) == np.sort(-im)):
            return np.real(out).copy()
    return out


def butter_poles(order: int) -> CArray:
    """Poles of the order-``order`` Butterworth low-pass with a 1 rad/s corner (left half
    plane, unit circle), in order of increasing angle."""
    m = np.arange(-order + 1, order, 2, dtype=np.float64)
    return np.asarray(-np.exp(1j * np.pi * m / (2 * order)), dtype=np.complex128)


def _highpass_gain(p0: CArray) -> float:
    # the low-pass -> high-pass map s -> wo/s scales the gain by prod(-z) / prod(-p), here
    # an empty (float) product over the prototype's zeros
    return float(np.real(np.prod(-np.zeros(0)) / np.prod(-p0)))


def butter_analog(order: int, corner_rad_s: float, btype: str) -> Rational:
    """Analog Butterworth ``lowpass`` or ``highpass`` of ``order`` with its -3 dB corner at
    ``corner_rad_s`` (rad/s): ``w^n / B_n(s)`` or ``b0 s^n / B_n(s)``."""
    n, wo = int(order), float(corner_rad_s)
    p0 = butter_poles(n)
    if btype == "lowpass":
        z, p, k = np.zeros(0), wo * p0, wo ** n
    elif btype == "highpass":
        z, p, k = np.zeros(n), wo / p0, _highpass_gain(p0)
    else:
        raise ValueError(f"butter_analog: btype must be lowpass or highpass, not {btype!r}")
    return Rational.of(np.multiply([k], poly(z)), poly(p))


def butter_sos(order: int, corner_hz: float | Sequence[float], btype: str,
               fs: float) -> Array:
    """Digital Butterworth ``lowpass``, ``highpass`` or ``bandpass`` (``corner_hz`` a pair)
    as second-order sections at sample rate ``fs`` (Hz), corners prewarped.

    Returns
    -------
    ndarray, shape (n, 6)
        Rows ``[b0 b1 b2 1 a1 a2]``, the gain in the first section.
    """
    wn = np.asarray(corner_hz, dtype=np.float64) / (fs / 2.0)
    if np.any(wn <= 0.0) or np.any(wn >= 1.0):
        raise ValueError(f"butter_sos: corners must be inside (0, fs/2), got {corner_hz}")
    # the digital design is on the normalised rate 2 (Nyquist 1), prewarped to the analog one
    warped = 2 * 2.0 * np.tan(np.pi * wn / 2.0)
    n = int(order)
    p0 = butter_poles(n)
    z: NDArray[np.generic]
    if btype == "lowpass":
        wo = float(warped)
        z, p, k = np.zeros(0), wo * p0, 1.0 * wo ** n
    elif btype == "highpass":
        wo = float(warped)
        z, p, k = np.zeros(n), wo / p0, _highpass_gain(p0)
    elif btype == "bandpass":
        bw, wo = float(warped[1] - warped[0]), float(np.sqrt(warped[0] * warped[1]))
        half = (p0 * bw / 2).astype(np.complex128)
        root = np.sqrt(half ** 2 - wo ** 2)
        # the band-pass zeros at s = 0 are complex-typed, as the pole pairs they come with
        z = np.zeros(n, dtype=np.complex128)
        p, k = np.concatenate((half + root, half - root)), 1.0 * bw ** n
    else:
        raise ValueError(f"butter_sos: btype must be lowpass, highpass or bandpass, not "
                         f"{btype!r}")
    zd, pd, kd = bilinear(z, p, k, 2.0)
    return zpk_to_sos(zd, pd, kd)


def tf_to_zpk(num: ArrayLike, den: ArrayLike) -> tuple[NDArray[np.generic],
                                                          NDArray[np.generic], float]:
    """Zeros, poles and gain of ``num(s) / den(s)`` (coefficients highest power first).

    The denominator is made monic; numerator coefficients that are then at most
    :data:`LEADING_ZERO` in front are dropped (a numerically vanished highest power).
    """
    d = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=np.float64)), "f")
    b = np.atleast_1d(np.asarray(num, dtype=np.float64)) / d[0]
    a = d / d[0]
    lead = 0
    while lead < b.size - 1 and abs(b[lead]) <= LEADING_ZERO:
        lead += 1
    b = b[lead:]
    k = float(b[0])
    return np.roots(b / b[0]), np.roots(a), k


def bilinear(z: ArrayLike, p: ArrayLike, k: float,
             fs: float) -> tuple[NDArray[np.generic], NDArray[np.generic], float]:
    """Bilinear (Tustin) map ``s = 2 fs (z - 1) / (z + 1)`` of zeros, poles and gain.

    ``fs`` (Hz) is the rate of the map (an effective rate when prewarped); each zero at
    infinity of a strictly proper system lands at z = -1.
    """
    zs = np.atleast_1d(np.asarray(z))
    ps = np.atleast_1d(np.asarray(p))
    extra = ps.size - zs.size
    if extra < 0:
        raise ValueError("bilinear: more zeros than poles (improper)")
    fs2 = 2.0 * fs
    zd = np.concatenate(((fs2 + zs) / (fs2 - zs), -np.ones(extra)))
    pd = (fs2 + ps) / (fs2 - ps)
    kd = k * float(np.real(np.prod(fs2 - zs) / np.prod(fs2 - ps)))
    return zd, pd, kd


def conjugate_pairs(x: ArrayLike) -> tuple[NDArray[np.generic], Array]:
    """Split roots into one member of each conjugate pair and the real ones.

    Returns
    -------
    pairs : ndarray (complex)
        The member with positive imaginary part, each the mean of the pair (conjugated),
        ordered by real part, then by imaginary magnitude.
    reals : ndarray (float)
        Roots whose imaginary part is within :data:`REAL_TOL` of their magnitude, ascending.

    Raises
    ------
    ValueError
        If a complex root has no conjugate.
    """
    v = np.atleast_1d(np.asarray(x))
    if v.size == 0:
        return np.zeros(0, dtype=np.complex128), np.zeros(0)
    v = v[np.lexsort((np.abs(v.imag), v.real))]
    real = np.abs(v.imag) <= REAL_TOL * np.abs(v)
    reals = np.asarray(v[real].real, dtype=np.float64)
    if real.all():
        # no pairs: an empty float array, so that concatenating keeps the reals float
        return np.zeros(0), reals
    c = v[~real]
    upper, lower = c[c.imag > 0], c[c.imag < 0]
    if upper.size != lower.size:
        raise ValueError("conjugate_pairs: a complex root has no conjugate")
    # within a run of (nearly) equal real parts, order by imaginary magnitude
    same = np.diff(upper.real) <= REAL_TOL * np.abs(upper[:-1])
    edges = np.diff(np.concatenate(([0], same.astype(int), [0])))
    for start, stop in zip(np.nonzero(edges > 0)[0], np.nonzero(edges < 0)[0], strict=True):
        for run in (upper[start:stop + 1], lower[start:stop + 1]):
            run[...] = run[np.lexsort([np.abs(run.imag)])]
    if np.any(np.abs(upper - lower.conj()) > REAL_TOL * np.abs(lower)):
        raise ValueError("conjugate_pairs: a complex root has no conjugate")
    return np.asarray((upper + lower.conj()) / 2, dtype=np.complex128), reals


def _nearest(candidates: NDArray[Any], target: complex, kind: str) -> int:
    """Index of the candidate nearest ``target`` among the ``real``, ``complex`` or ``any``."""
    order = np.argsort(np.abs(candidates - target), kind="stable")
    if kind == "any":
        return int(order[0])
    real = np.isreal(candidates[order])
    return int(order[np.nonzero(real if kind == "real" else ~real)[0][0]])


def _section(zeros: Sequence[complex], poles: Sequence[complex]) -> Array:
    """One section ``[b0 b1 b2 1 a1 a2]`` with up to two zeros and poles, gain 1 (a missing
    root leaves the leading coefficients 0)."""
    sec = np.zeros(6)
    b, a = poly(np.asarray(zeros)), poly(np.asarray(poles))
    sec[3 - b.size:3] = np.real(b)
    sec[6 - a.size:6] = np.real(a)
    return sec


def zpk_to_sos(z: ArrayLike, p: ArrayLike, k: float) -> Array:
    """Digital zeros, poles and gain as second-order sections.

    Each section takes the pole nearest the unit circle left, with the zero nearest it; the
    sections are ordered so the poles nearest the circle come last and the gain sits in the
    first (``scipy.signal.zpk2sos``, pairing "nearest", documents the rules). Poles and zeros
    are padded with roots at z = 0 to an even count of each.

    Returns
    -------
    ndarray, shape (n, 6)
        Rows ``[b0 b1 b2 1 a1 a2]``.
    """
    zs, ps = np.atleast_1d(np.asarray(z)), np.atleast_1d(np.asarray(p))
    if zs.size == 0 and ps.size == 0:
        return np.array([[float(k), 0.0, 0.0, 1.0, 0.0, 0.0]])
    n = max(zs.size, ps.size)
    n += n % 2
    zs = np.concatenate((zs, np.zeros(n - zs.size)))
    ps = np.concatenate((ps, np.zeros(n - ps.size)))
    zr: NDArray[np.generic] = np.concatenate(conjugate_pairs(zs))
    pr: NDArray[np.generic] = np.concatenate(conjugate_pairs(ps))
    sos = np.zeros((n // 2, 6))
    for si in range(n // 2 - 1, -1, -1):
        i = int(np.argmin(np.abs(1.0 - np.abs(pr))))
        p1 = pr[i]
        pr = np.delete(pr, i)
        reals_left = int(np.isreal(pr).sum())
        if np.isreal(p1) and reals_left == 0:
            # the last real pole: a first-order section, padded with a root at 0
            j = _nearest(zr, p1, "real")
            sos[si] = _section([zr[j], 0], [p1, 0])
            zr = np.delete(zr, j)
            continue
        if (pr.size + 1 == zr.size and not np.isreal(p1) and reals_left == 1
                and int(np.isreal(zr).sum()) == 1):
            # one real pole and one real zero left for the remaining sections: take a
            # complex zero here so that the last section pairs the reals
            j = _nearest(zr, p1, "complex")
            z1 = zr[j]
            zr = np.delete(zr, j)
            sos[si] = _section([z1, np.conj(z1)], [p1, np.conj(p1)])
            continue
        if np.isreal(p1):
            reals = np.flatnonzero(np.isreal(pr))
            i2 = int(reals[np.argmin(np.abs(1.0 - np.abs(pr[reals])))])
            p2 = pr[i2]
            pr = np.delete(pr, i2)
        else:
            p2 = np.conj(p1)
        if zr.size == 0:
            sos[si] = _section([], [p1, p2])
            continue
        j = _nearest(zr, p1, "any")
        z1 = zr[j]
        zr = np.delete(zr, j)
        if not np.isreal(z1):
            sos[si] = _section([z1, np.conj(z1)], [p1, p2])
        elif zr.size:
            j = _nearest(zr, p1, "real")
            sos[si] = _section([z1, zr[j]], [p1, p2])
            zr = np.delete(zr, j)
        else:
            sos[si] = _section([z1], [p1, p2])
    sos[0, :3] *= float(np.real(k))
    return sos


def sos_steady_state(sos: ArrayLike) -> Array:
    """Delay states, shape (n, 2), of a unit constant input's steady state in the transposed
    direct form II sections ``sos`` (n, 6) (``scipy.signal.sosfilt_zi``): scale by the input
    level for a bumpless start.

    Raises
    ------
    numpy.linalg.LinAlgError
        When a section has a pole at z = 1 (no steady state).
    """
    s = np.asarray(sos, dtype=np.float64)
    if s.ndim != 2 or s.shape[1] != 6:
        raise ValueError(f"sos_steady_state: sos must be (n, 6), got {s.shape}")
    zi = np.empty((s.shape[0], 2))
    scale = 1.0
    for i, row in enumerate(s):
        b, a = row[:3], row[3:]
        if a[0] != 1.0:
            b, a = b / a[0], a / a[0]
        # (I - A^T) zi = b[1:] - a[1:] b0, A the companion matrix of a
        lhs = np.array([[1.0 + a[1], -1.0], [a[2], 1.0]])
        zi[i] = scale * np.linalg.solve(lhs, b[1:] - a[1:] * b[0])
        scale *= np.sum(b) / np.sum(a)
    return zi


def sos_response(sos: ArrayLike, f_hz: ArrayLike, fs: float) -> CArray:
    """Complex response of digital sections ``sos`` (n, 6) at ``f_hz`` (Hz, 1-D) for the
    sample rate ``fs`` (Hz) (``scipy.signal.sosfreqz`` at given frequencies)."""
    zm1 = np.exp(-1j * (2 * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=np.float64)) / fs))
    h: CArray | float = 1.0
    for row in np.asarray(sos, dtype=np.float64).reshape(-1, 6):
        h = h * (_horner(row[:3], zm1) / _horner(row[3:], zm1))
    return np.asarray(h, dtype=np.complex128)


def _horner(c: Array, x: CArray) -> CArray:
    # sum c[i] x^i from the highest power down
    acc = np.full(x.shape, c[-1], dtype=np.complex128)
    for ci in c[-2::-1]:
        acc = ci + acc * x
    return acc


__all__ = ["LEADING_ZERO", "REAL_TOL", "Rational", "bilinear", "butter_analog",
           "butter_poles", "butter_sos", "conjugate_pairs", "poly", "sos_response",
           "sos_steady_state",
           "tf_to_zpk", "unity", "zpk_to_sos"]
