"""Continuous controller filters (python-control) and their discrete second-order sections.

Designs are continuous transfer functions so that :mod:`.analytics` analyses exactly what the
loops run; :func:`to_sos` turns one into Tustin second-order sections and :class:`SosFilter`
runs them sample by sample, vectorised over channels, without hidden state.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, cast

import control as ct
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from dcsms_ros.core.config import FeedbackConfig, FeedforwardConfig
from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]
TF = Any  # control.TransferFunction (python-control ships no type stubs)

#: Largest channels x sections a :class:`SosFilter` steps on Python floats (numpy beyond: one
#: numpy call per section costs ~1 us, one float section ~0.25 us per channel).
SCALAR_MAX = 12
#: A pass-through second-order section ``[b0 b1 b2 a0 a1 a2]``.
IDENTITY_SECTION = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0])


def _tf(num: ArrayLike, den: ArrayLike) -> TF:
    return ct.tf(np.atleast_1d(np.asarray(num, float)), np.atleast_1d(np.asarray(den, float)))


def unity() -> TF:
    """The identity transfer function 1."""
    return _tf([1.0], [1.0])


def _butter_ba(order: int, corner_hz: float, btype: str) -> tuple[Array, Array]:
    b, a = signal.butter(int(order), 2.0 * math.pi * corner_hz, btype=btype, analog=True)
    return np.asarray(b, float), np.asarray(a, float)


def highpass(order: int, corner_hz: float) -> TF:
    """Butterworth high-pass ``s^n / B_n(s)`` with -3 dB corner ``corner_hz`` (Hz); 0 -> 1."""
    if corner_hz <= 0.0:
        return unity()
    return _tf(*_butter_ba(order, corner_hz, "highpass"))


def lowpass(order: int, corner_hz: float) -> TF:
    """Butterworth low-pass of ``order`` with -3 dB corner ``corner_hz`` (Hz); 0 -> 1."""
    if corner_hz <= 0.0:
        return unity()
    return _tf(*_butter_ba(order, corner_hz, "lowpass"))


def notch(center_hz: float, q: float) -> TF:
    """Notch ``(s^2 + w^2) / (s^2 + (w/Q) s + w^2)``, ``w = 2 pi center_hz``; 0 -> 1."""
    if center_hz <= 0.0:
        return unity()
    w = 2.0 * math.pi * center_hz
    return _tf([1.0, 0.0, w * w], [1.0, w / q, w * w])


def leadlag(zero_hz: float, pole_hz: float) -> TF:
    """Lead-lag ``(s/wz + 1) / (s/wp + 1)``; ``zero_hz == 0`` disables it (-> 1).

    Raises
    ------
    ConfigError
        If the zero is set but the pole is 0 (the stage would be improper).
    """
    if zero_hz <= 0.0:
        return unity()
    if pole_hz <= 0.0:
        raise ConfigError(f"lead-lag: lead_hz={zero_hz:g} needs lag_hz > 0 (got {pole_hz:g})")
    wz, wp = 2.0 * math.pi * zero_hz, 2.0 * math.pi * pole_hz
    return _tf([1.0 / wz, 1.0], [1.0 / wp, 1.0])


def feedback_tf(fb: FeedbackConfig, axis: int) -> TF:
    """Velocity-feedback compensator of one axis, ``gain[axis] * HP * LP * notch * leadlag``.

    Parameters
    ----------
    fb : FeedbackConfig
        The stage's feedback settings.
    axis : int
        0..5 for x y z rx ry rz (1dof uses 2).

    Returns
    -------
    control.TransferFunction
        Velocity (m/s or rad/s) -> force (N or N*m). The loop applies ``-feedback_tf * v``.
    """
    g = float(fb.gain[axis])
    return (g * highpass(fb.highpass_order, fb.highpass_hz) * lowpass(fb.lowpass_order,
            fb.lowpass_hz) * notch(fb.notch_hz, fb.notch_q) * leadlag(fb.lead_hz, fb.lag_hz))


def feedforward_tf(ff: FeedforwardConfig, c1: float, k1: float) -> TF:
    """Ground feedforward ``gain * (c1 + k1/s) * HP * LP`` with no pole at s = 0.

    The integrator of ``k1/s`` is cancelled symbolically against one ``s`` of the Butterworth
    high-pass numerator ``s^n``, so the result is proper and stable.

    Parameters
    ----------
    ff : FeedforwardConfig
        Feedforward settings (``highpass_hz > 0`` is required).
    c1, k1 : float
        Stage-1 suspension damping (N*s/m) and stiffness (N/m) along the axis.

    Returns
    -------
    control.TransferFunction
        Ground velocity (m/s) -> force (N). The loop applies ``-feedforward_tf * v_b``.
    """
    if ff.highpass_hz <= 0.0:
        raise ConfigError("feedforward.highpass_hz must be > 0 to cancel the 1/s of k1/s")
    b, a = _butter_ba(ff.highpass_order, ff.highpass_hz, "highpass")
    b = np.trim_zeros(b, "f")
    if b.size < 2 or np.any(b[1:]):
        raise ConfigError("feedforward.highpass_order must be >= 1")
    # b = b0 * s^n: dropping one trailing zero divides by s, cancelling the 1/s of k1/s exactly
    num = ff.gain * np.polymul([c1, k1], b[:-1])
    return _tf(num, a) * lowpass(ff.lowpass_order, ff.lowpass_hz)


def _num_den(tf: TF) -> tuple[Array, Array]:
    if tf.ninputs != 1 or tf.noutputs != 1:
        raise ValueError("to_sos: only SISO transfer functions are supported")
    num = np.trim_zeros(np.asarray(tf.num[0][0], dtype=np.float64), "f")
    den = np.trim_zeros(np.asarray(tf.den[0][0], dtype=np.float64), "f")
    return (num if num.size else np.zeros(1)), den


def to_sos(tf: TF, fs: float, prewarp_hz: float = 0.0) -> Array:
    """Tustin (bilinear) discretisation into second-order sections.

    Parameters
    ----------
    tf : control.TransferFunction
        Continuous SISO, proper (``deg num <= deg den``).
    fs : float
        Sample rate in Hz.
    prewarp_hz : float
        Frequency (Hz, below fs/2) where the discrete response equals the continuous one
        exactly; 0 for plain Tustin. A notch needs it: warping moves a sharp notch by ~1 %.

    Returns
    -------
    ndarray, shape (n, 6)
        Rows ``[b0 b1 b2 1 a1 a2]`` (scipy ``sosfilt`` layout); a static gain gives one section.

    Raises
    ------
    ValueError
        For an improper or MIMO transfer function.
    """
    num, den = _num_den(tf)
    if not np.any(num):
        return np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    if num.size > den.size:
        raise ValueError(f"to_sos: improper transfer function (numerator degree {num.size - 1} "
                         f"> denominator degree {den.size - 1})")
    if den.size == 1:
        sec = IDENTITY_SECTION.copy()
        sec[0] = num[0] / den[0]
        return sec[None, :]
    z, p, k = signal.tf2zpk(num, den)
    fs_eff = fs
    if prewarp_hz > 0.0:
        if prewarp_hz >= fs / 2.0:
            raise ValueError(f"to_sos: prewarp_hz={prewarp_hz:g} must be below fs/2")
        w0 = 2.0 * math.pi * prewarp_hz
        fs_eff = w0 / (2.0 * math.tan(w0 / (2.0 * fs)))
    zd, pd, kd = signal.bilinear_zpk(z, p, k, fs_eff)
    sos = signal.zpk2sos(zd, pd, kd)
    return np.asarray(np.real(sos), dtype=np.float64)


def feedback_sos(fb: FeedbackConfig, axis: int, fs: float) -> Array:
    """The SOS a feedback loop runs: :func:`feedback_tf` prewarped at the notch (if any)."""
    return to_sos(feedback_tf(fb, axis), fs, fb.notch_hz if 0.0 < fb.notch_hz < fs / 2 else 0.0)


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
                    zi = signal.sosfilt_zi(sos) * u[c]
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


def dc_gain(tf: TF) -> float:
    """Gain at s = 0 (inf when there is an integrator)."""
    num, den = _num_den(tf)
    return float(num[-1] / den[-1]) if den[-1] != 0.0 else math.inf


__all__ = [
    "IDENTITY_SECTION", "TF", "SosFilter", "dc_gain", "feedback_sos", "feedback_tf",
    "feedforward_tf", "highpass", "leadlag", "lowpass", "notch", "sos_state_space", "to_sos",
    "unity",
]
