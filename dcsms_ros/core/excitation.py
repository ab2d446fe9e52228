"""Actuator excitation: band-limited white noise, swept sine and stepped sine on one stage axis.

An excitation is a wrench on one stage, added to the controllers' wrench of that stage *before*
allocation (the ``excite`` input of :func:`.loop_model.loop_model`): it goes through the drive
matrix, the actuator limit and the stage-below reaction exactly as a controller's force does.

Specification text (``dcsms sim --excite``, the excitation node's ``spec`` parameter)::

    STAGE.AXIS:white:RMS[:LO-HI]          band-limited white noise, RMS in N (N*m for rx ry rz)
    STAGE.AXIS:sweep:AMP[:LO-HI[:T]]      logarithmic sine sweep LO -> HI Hz, amplitude AMP,
                                          one sweep every T s (default: the whole run)
    STAGE.AXIS:stepped:AMP[:LO-HI[:N]]    N sines (default 12), log-spaced LO .. HI Hz, each
                                          held for T/N s (T: the whole run)

``STAGE`` is ``stage1`` … ``stageN``; ``AXIS`` is ``z`` in 1-DOF, one of ``x y z rx ry rz`` in
6-DOF. ``LO-HI`` defaults to :data:`DEFAULT_BAND_HZ`. ``stage1.z:white:5`` is 5 N RMS;
``stage2.x:sweep:20:0.5-50`` is a 20 N sweep from 0.5 to 50 Hz. A suffix ``@T0-T1`` (s) keeps
the excitation on only from T0 to T1 of the run (a sweep or stepped sine then starts at T0 and
its default period is T1 - T0), e.g. ``stage1.z:white:5@10-40``.

The signal of sample k depends only on the specifications, the rate, the run length and the seed
(:class:`Excitation` serves the same values per sample or per block), so the excitation node and
the batch engine add the very same wrenches.

Limits: the peak actuator force the excitation alone asks for (a sine's amplitude, or
:data:`WHITE_PEAK_SIGMA` times the white noise's RMS, which the generator clips to) must stay
within the actuator limit of the stage, after allocation through the drive matrix; otherwise the
specification is refused (:class:`~dcsms_ros.errors.ConfigError`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import Allocator
from dcsms_ros.core.disturbance import BandNoise
from dcsms_ros.core.schema import AXES6
from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]

KINDS = ("white", "sweep", "stepped")
#: Default band (Hz) of every kind.
DEFAULT_BAND_HZ = (0.5, 100.0)
#: The white-noise generator clips at this many standard deviations (the limit check uses it).
WHITE_PEAK_SIGMA = 4.0
#: Steps of a stepped sine when the specification gives none.
DEFAULT_STEPS = 12
#: Period (s) of a sweep or stepped sine when neither the specification nor the run gives one.
DEFAULT_PERIOD_S = 60.0
#: Stream id of the excitation noise (apart from the disturbance and sensor-noise streams).
_STREAM = 11

_SPEC = re.compile(r"^\s*(stage[1-9][0-9]*)\.([a-z]+)\s*:\s*([a-z]+)\s*:\s*([^:]+?)\s*"
                   r"(?::\s*([^:]+?)\s*)?(?::\s*([^:]+?)\s*)?$")


@dataclass(frozen=True)
class ExcitationSpec:
    """One excitation.

    Attributes
    ----------
    stage : int
        1-based stage it pushes (its actuators; the reaction acts on the stage below).
    axis : str
        ``x y z rx ry rz`` (``z`` only in 1-DOF).
    kind : str
        ``white``, ``sweep`` or ``stepped``.
    amplitude : float
        White: RMS; sweep and stepped: sine amplitude (N, or N*m for a rotation axis).
    band_hz : (float, float)
        Band (white), start and end frequency (sweep), lowest and highest step (stepped), Hz.
    period_s : float
        Sweep: duration of one sweep, s (0: the whole run).
    steps : int
        Stepped: number of frequencies.
    window_s : (float, float) or None
        On only from ``window_s[0]`` to ``window_s[1]`` of the run, s (None: always).
    """

    stage: int
    axis: str
    kind: str
    amplitude: float
    band_hz: tuple[float, float] = DEFAULT_BAND_HZ
    period_s: float = 0.0
    steps: int = DEFAULT_STEPS
    window_s: tuple[float, float] | None = None

    @property
    def stage_name(self) -> str:
        return f"stage{self.stage}"

    @property
    def text(self) -> str:
        """The specification written back (canonical form)."""
        lo, hi = self.band_hz
        extra = ""
        if self.kind == "sweep" and self.period_s > 0:
            extra = f":{self.period_s:g}"
        elif self.kind == "stepped":
            extra = f":{self.steps}"
        if self.window_s is not None:
            extra += f"@{self.window_s[0]:g}-{self.window_s[1]:g}"
        return f"{self.stage_name}.{self.axis}:{self.kind}:{self.amplitude:g}:{lo:g}-{hi:g}{extra}"

    @property
    def unit(self) -> str:
        return "N*m" if self.axis.startswith("r") else "N"


def _number(text: str, what: str, spec: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise ConfigError(f"--excite {spec!r}: {what} {text!r} is not a number")
    return v


def parse_spec(text: str) -> ExcitationSpec:
    """Parse one specification (module docstring); the stage and axis are checked against a
    configuration by :func:`check_specs`.

    Raises
    ------
    ConfigError
        A malformed specification (the message shows the expected form).
    """
    body, at, window = text.partition("@")
    m = _SPEC.match(body)
    form = ("expected STAGE.AXIS:KIND:AMPLITUDE[:LO-HI[:T or N]][@T0-T1], e.g. "
            "stage1.z:white:5")
    if m is None:
        raise ConfigError(f"--excite {text!r}: {form}")
    win: tuple[float, float] | None = None
    if at:
        parts = window.split("-")
        if len(parts) != 2:
            raise ConfigError(f"--excite {text!r}: window {window!r}: expected @T0-T1 in s")
        t0, t1 = (_number(p, "window time", text) for p in parts)
        if not 0 <= t0 < t1:
            raise ConfigError(f"--excite {text!r}: window {window!r}: need 0 <= T0 < T1 (s)")
        win = (t0, t1)
    stage, axis, kind, amp, band, extra = m.groups()
    if axis not in AXES6:
        raise ConfigError(f"--excite {text!r}: unknown axis {axis!r}; one of {' '.join(AXES6)}")
    if kind not in KINDS:
        raise ConfigError(f"--excite {text!r}: unknown kind {kind!r}; one of {', '.join(KINDS)}")
    amplitude = _number(amp, "amplitude", text)
    if not amplitude > 0:
        raise ConfigError(f"--excite {text!r}: the amplitude must be > 0")
    lo, hi = DEFAULT_BAND_HZ
    if band is not None:
        parts = band.split("-")
        if len(parts) != 2:
            raise ConfigError(f"--excite {text!r}: band {band!r}: expected LO-HI in Hz")
        lo, hi = (_number(p, "band edge", text) for p in parts)
        if not 0 < lo < hi:
            raise ConfigError(f"--excite {text!r}: band {band!r}: need 0 < LO < HI (Hz)")
    period, steps = 0.0, DEFAULT_STEPS
    if extra is not None:
        if kind == "white":
            raise ConfigError(f"--excite {text!r}: white noise takes no third field")
        if kind == "sweep":
            period = _number(extra, "sweep period", text)
            if not period > 0:
                raise ConfigError(f"--excite {text!r}: the sweep period must be > 0 s")
        else:
            if not extra.isdigit() or not 1 <= int(extra) <= 1000:
                raise ConfigError(f"--excite {text!r}: steps {extra!r}: an integer 1..1000")
            steps = int(extra)
    return ExcitationSpec(int(stage[5:]), axis, kind, amplitude, (lo, hi), period, steps, win)


def axis_index(cfg: SystemConfig, axis: str) -> int:
    """Index of ``axis`` in a stage's dof vector (0 in 1-DOF, where only ``z`` exists)."""
    if cfg.plant.dof == 1 and axis != "z":
        raise ConfigError(f"excitation axis {axis!r}: a 1dof plant has only z")
    return axis_index_dof(cfg.plant.dof, axis)


def peak_force(cfg: SystemConfig, spec: ExcitationSpec) -> tuple[float, float]:
    """(peak actuator force the excitation alone asks for, that stage's actuator limit), N."""
    alloc = Allocator(cfg, spec.stage)
    col = alloc.pinv[:, axis_index(cfg, spec.axis)]
    peak = spec.amplitude * (WHITE_PEAK_SIGMA if spec.kind == "white" else 1.0)
    return float(peak * np.max(np.abs(col))), alloc.limit


def check_specs(cfg: SystemConfig, specs: Sequence[ExcitationSpec]) -> None:
    """Check specifications against a configuration.

    Raises
    ------
    ConfigError
        An unknown stage or axis, specifications on two different stages (the excitation
        wrench has one frame: record one stage at a time), one axis given twice, a band beyond
        Nyquist, or a peak actuator force beyond the limit (summed over the axes of the stage).
    """
    if not specs:
        return
    n = cfg.plant.num_stages
    nyq = cfg.plant.rate_hz / 2.0
    stages = sorted({s.stage for s in specs})
    if len(stages) > 1:
        raise ConfigError("--excite: all excitations must push one stage (the excitation "
                          "wrench has one frame; record one stage per run), got "
                          + ", ".join(f"stage{s}" for s in stages))
    if stages[0] > n:
        raise ConfigError(f"--excite: stage{stages[0]} does not exist ({n} stages)")
    axes = [s.axis for s in specs]
    if len(set(axes)) != len(axes):
        raise ConfigError("--excite: one axis is excited twice; give each axis once")
    total = 0.0
    limit = 0.0
    for s in specs:
        axis_index(cfg, s.axis)
        if s.band_hz[1] >= nyq:
            raise ConfigError(f"--excite {s.text!r}: {s.band_hz[1]:g} Hz is at or beyond "
                              f"Nyquist ({nyq:g} Hz)")
        peak, limit = peak_force(cfg, s)
        total += peak
    if total > limit:
        raise ConfigError(f"--excite: peak actuator force {total:.4g} N (white noise counted "
                          f"at {WHITE_PEAK_SIGMA:g} sigma) exceeds the actuator limit "
                          f"{limit:.4g} N of stage{stages[0]}")


class Excitation:
    """The excitation wrenches of a run, served sample by sample or block by block.

    Parameters
    ----------
    cfg : SystemConfig
    specs : sequence of ExcitationSpec
        Checked with :func:`check_specs`; may be empty (all zeros).
    seed : int
        Seed of the white-noise stream(s) (a run's disturbance seed).
    duration_s : float
        Length of the run, s: the default period of sweeps and stepped sines (0: unknown,
        :data:`DEFAULT_PERIOD_S`).
    """

    def __init__(self, cfg: SystemConfig, specs: Sequence[ExcitationSpec], seed: int,
                 duration_s: float = 0.0) -> None:
        check_specs(cfg, specs)
        self.specs = tuple(specs)
        self.dof = cfg.plant.dof
        self.num_stages = cfg.plant.num_stages
        self.fs = cfg.plant.rate_hz
        self.stage = specs[0].stage if specs else 0
        self.k = 0
        self._run = duration_s if duration_s > 0 else DEFAULT_PERIOD_S
        self._noise: list[BandNoise | None] = []
        for i, s in enumerate(self.specs):
            if s.kind == "white":
                ss = np.random.SeedSequence(int(seed), spawn_key=(_STREAM, i))
                self._noise.append(BandNoise(s.amplitude, s.band_hz, self.fs, 1,
                                             np.random.default_rng(ss)))
            else:
                self._noise.append(None)

    @property
    def active(self) -> bool:
        return bool(self.specs)

    @property
    def stage_name(self) -> str:
        """``stage<i>`` of the pushed stage ("" without specifications)."""
        return f"stage{self.stage}" if self.specs else ""

    def _tone(self, s: ExcitationSpec, t: Array) -> Array:
        lo, hi = s.band_hz
        run = self._run if s.window_s is None else s.window_s[1] - s.window_s[0]
        period = s.period_s if s.period_s > 0 else run
        if s.kind == "sweep":
            tau = np.mod(t, period)
            rate = math.log(hi / lo) / period
            phase = 2 * math.pi * lo * np.expm1(rate * tau) / rate
            return np.asarray(s.amplitude * np.sin(phase), dtype=np.float64)
        freqs = np.geomspace(lo, hi, s.steps) if s.steps > 1 else np.array([lo])
        dwell = period / s.steps
        idx = np.minimum((np.mod(t, period) // dwell).astype(np.int64), s.steps - 1)
        t_in = np.mod(t, period) - idx * dwell
        return np.asarray(s.amplitude * np.sin(2 * math.pi * freqs[idx] * t_in),
                          dtype=np.float64)

    def block(self, n: int) -> Array:
        """The next ``n`` samples, shape (n, N, dof) (N, N*m); zero on the other stages."""
        out = np.zeros((n, self.num_stages, self.dof))
        t = (self.k + np.arange(n)) / self.fs
        for s, noise in zip(self.specs, self._noise, strict=True):
            t_on = t if s.window_s is None else t - s.window_s[0]
            if noise is not None:
                lim = WHITE_PEAK_SIGMA * s.amplitude
                v = np.clip(noise.block(n)[:, 0], -lim, lim)  # drawn on or off: one stream
            else:
                v = self._tone(s, t_on)
            if s.window_s is not None:
                v = np.where((t_on >= 0) & (t < s.window_s[1]), v, 0.0)
            out[:, s.stage - 1, axis_index_dof(self.dof, s.axis)] = v
        self.k += n
        return out

    def next(self) -> Array:
        """The next sample, shape (N, dof)."""
        return self.block(1)[0]

    def at(self, k: int) -> Array:
        """The wrench of sample ``k`` (>= the next one), shape (N, dof); the samples before it
        are drawn and dropped, so a sample's value never depends on which others were asked
        for (a real-time node that misses samples stays on the batch engine's sequence).

        Raises
        ------
        ValueError
            ``k`` was served already.
        """
        if k < self.k:
            raise ValueError(f"excitation sample {k} was served already (next: {self.k})")
        while k > self.k:
            self.block(min(k - self.k, 1 << 16))
        return self.next()


def axis_index_dof(dof: int, axis: str) -> int:
    """Index of ``axis`` in a ``dof`` vector (1-DOF: 0 for z)."""
    return 0 if dof == 1 else AXES6.index(axis)


def excitation_signal(cfg: SystemConfig, specs: Sequence[ExcitationSpec], steps: int,
                      seed: int) -> Array:
    """The whole excitation of a run of ``steps`` samples, shape (steps, N, dof)."""
    return Excitation(cfg, specs, seed, steps / cfg.plant.rate_hz).block(steps)


__all__ = ["DEFAULT_BAND_HZ", "KINDS", "WHITE_PEAK_SIGMA", "Excitation", "ExcitationSpec",
           "axis_index", "check_specs", "excitation_signal", "parse_spec", "peak_force"]
