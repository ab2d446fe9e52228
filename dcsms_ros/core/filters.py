"""Continuous controller filters and their discrete second-order sections, on numpy alone.

Designs are continuous transfer functions (:class:`.filterdesign.Rational`) so that
:mod:`.analytics` analyses exactly what the loops run (it wraps them into python-control);
:func:`to_sos` turns one into Tustin second-order sections, which
:class:`.sosfilter.SosFilter` runs sample by sample.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import FeedbackConfig, FeedforwardConfig
from dcsms_ros.core.filterdesign import (
    Rational,
    bilinear,
    butter_analog,
    tf_to_zpk,
    unity,
    zpk_to_sos,
)
from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]
TF = Rational

#: A pass-through second-order section ``[b0 b1 b2 a0 a1 a2]``.
IDENTITY_SECTION = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0])


def highpass(order: int, corner_hz: float) -> TF:
    """Butterworth high-pass ``s^n / B_n(s)`` with -3 dB corner ``corner_hz`` (Hz); 0 -> 1."""
    if corner_hz <= 0.0:
        return unity()
    return butter_analog(order, 2.0 * math.pi * corner_hz, "highpass")


def lowpass(order: int, corner_hz: float) -> TF:
    """Butterworth low-pass of ``order`` with -3 dB corner ``corner_hz`` (Hz); 0 -> 1."""
    if corner_hz <= 0.0:
        return unity()
    return butter_analog(order, 2.0 * math.pi * corner_hz, "lowpass")


def notch(center_hz: float, q: float) -> TF:
    """Notch ``(s^2 + w^2) / (s^2 + (w/Q) s + w^2)``, ``w = 2 pi center_hz``; 0 -> 1."""
    if center_hz <= 0.0:
        return unity()
    w = 2.0 * math.pi * center_hz
    return Rational.of([1.0, 0.0, w * w], [1.0, w / q, w * w])


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
    return Rational.of([1.0 / wz, 1.0], [1.0 / wp, 1.0])


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
    Rational
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
    Rational
        Ground velocity (m/s) -> force (N). The loop applies ``-feedforward_tf * v_b``.
    """
    if ff.highpass_hz <= 0.0:
        raise ConfigError("feedforward.highpass_hz must be > 0 to cancel the 1/s of k1/s")
    hp = butter_analog(ff.highpass_order, 2.0 * math.pi * ff.highpass_hz, "highpass")
    b, a = hp.num, hp.den
    if b.size < 2 or np.any(b[1:]):
        raise ConfigError("feedforward.highpass_order must be >= 1")
    # b = b0 * s^n: dropping one trailing zero divides by s, cancelling the 1/s of k1/s exactly
    num = ff.gain * np.polymul([c1, k1], b[:-1])
    return Rational.of(num, a) * lowpass(ff.lowpass_order, ff.lowpass_hz)


def _num_den(tf: TF) -> tuple[Array, Array]:
    num = np.trim_zeros(np.asarray(tf.num, dtype=np.float64), "f")
    den = np.trim_zeros(np.asarray(tf.den, dtype=np.float64), "f")
    return (num if num.size else np.zeros(1)), den


def to_sos(tf: TF, fs: float, prewarp_hz: float = 0.0) -> Array:
    """Tustin (bilinear) discretisation into second-order sections.

    Parameters
    ----------
    tf : Rational
        Continuous, proper (``deg num <= deg den``).
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
        For an improper transfer function.
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
    z, p, k = tf_to_zpk(num, den)
    fs_eff = fs
    if prewarp_hz > 0.0:
        if prewarp_hz >= fs / 2.0:
            raise ValueError(f"to_sos: prewarp_hz={prewarp_hz:g} must be below fs/2")
        w0 = 2.0 * math.pi * prewarp_hz
        fs_eff = w0 / (2.0 * math.tan(w0 / (2.0 * fs)))
    return zpk_to_sos(*bilinear(z, p, k, fs_eff))


def feedback_sos(fb: FeedbackConfig, axis: int, fs: float) -> Array:
    """The SOS a feedback loop runs: :func:`feedback_tf` prewarped at the notch (if any)."""
    return to_sos(feedback_tf(fb, axis), fs, fb.notch_hz if 0.0 < fb.notch_hz < fs / 2 else 0.0)


def dc_gain(tf: TF) -> float:
    """Gain at s = 0 (inf when there is an integrator)."""
    num, den = _num_den(tf)
    return float(num[-1] / den[-1]) if den[-1] != 0.0 else math.inf


__all__ = [
    "IDENTITY_SECTION", "TF", "dc_gain", "feedback_sos", "feedback_tf",
    "feedforward_tf", "highpass", "leadlag", "lowpass", "notch", "to_sos",
    "unity",
]
