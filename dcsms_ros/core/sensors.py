"""Geophone model: transfer function, low-frequency extension, channel layout, discrete array.

Readings are in m/s as a real rig publishes them: output volts divided by the nominal
sensitivity, so they keep the geophone's second-order roll-off below its natural frequency.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.config import SensorConfig, SystemConfig
from dcsms_ros.core.filterdesign import Rational, unity
from dcsms_ros.core.filters import TF, to_sos
from dcsms_ros.core.geometry import sensor_matrix
from dcsms_ros.core.sosfilter import SosFilter
from dcsms_ros.core.topics import body_names

Array = NDArray[np.float64]

#: Gaussian samples drawn from the Generator at a time (speed; results do not depend on it).
NOISE_BLOCK = 1024


def geophone_tf(s: SensorConfig) -> TF:
    """Geophone velocity response ``s^2 / (s^2 + 2 zeta wn s + wn^2)`` (m/s -> m/s).

    The sensitivity (V/(m/s)) only scales volts and cancels in the published reading; with
    ``s.dynamics`` False the sensor is ideal and the result is 1.
    """
    if not s.dynamics:
        return unity()
    wn = 2.0 * math.pi * s.natural_frequency_hz
    return Rational.of([1.0, 0.0, 0.0], [1.0, 2.0 * s.damping_ratio * wn, wn * wn])


def extension_tf(s: SensorConfig) -> TF:
    """Low-frequency extension ``(s^2 + 2 zeta wn s + wn^2) / (s^2 + 2 zeta_e we s + we^2)``.

    Cascaded with :func:`geophone_tf` it gives a geophone with natural frequency
    ``extension_hz`` and damping ``extension_damping``. Identity when ``extension_hz`` is 0 or
    the sensor is ideal.
    """
    if not s.dynamics or s.extension_hz <= 0.0:
        return unity()
    wn = 2.0 * math.pi * s.natural_frequency_hz
    we = 2.0 * math.pi * s.extension_hz
    return Rational.of([1.0, 2.0 * s.damping_ratio * wn, wn * wn],
                       [1.0, 2.0 * s.extension_damping * we, we * we])


class Channel(NamedTuple):
    """One geophone channel: ``body`` name, channel ``name`` (``<body>/z`` or ``<body>/g<k>``),
    ``position`` (m, world) and unit measuring ``direction``."""

    body: str
    name: str
    position: tuple[float, float, float]
    direction: tuple[float, float, float]


def _body_refs(cfg: SystemConfig) -> list[tuple[str, tuple[float, float, float]]]:
    """(body name, reference point) in cascade order."""
    names = body_names(cfg.plant.num_stages)
    refs = [(0.0, 0.0, 0.0)] + [tuple(st.com) for st in cfg.plant.stages]
    return [(n, (float(r[0]), float(r[1]), float(r[2]))) for n, r in zip(names, refs, strict=True)]


def channel_layout(cfg: SystemConfig) -> list[Channel]:
    """Every channel, ordered ground, stage1 … stageN (1dof: one vertical ``<body>/z`` each)."""
    names = body_names(cfg.plant.num_stages)
    if cfg.plant.dof == 1:
        return [Channel(b, f"{b}/z", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)) for b in names]
    sets = [cfg.plant.ground_sensors] + [st.sensors for st in cfg.plant.stages]
    out = []
    for b, tr in zip(names, sets, strict=True):
        for k, (p, d) in enumerate(zip(tr.position, tr.direction, strict=True), start=1):
            out.append(Channel(b, f"{b}/g{k}", tuple(p), tuple(d)))  # type: ignore[arg-type]
    return out


def body_sensor_matrices(cfg: SystemConfig) -> list[tuple[str, slice, Array]]:
    """Per body: (name, its slice of the channel vector, sensor matrix S (n_b, dof)).

    S maps the body's twist at its reference point (ground: world origin; stage: its com) to its
    channel velocities; 1dof gives ``[[1.0]]``.
    """
    layout = channel_layout(cfg)
    out = []
    start = 0
    for body, ref in _body_refs(cfg):
        rows = [c for c in layout if c.body == body]
        if cfg.plant.dof == 1:
            s = np.ones((1, 1))
        else:
            s = sensor_matrix(np.array([c.position for c in rows]),
                              np.array([c.direction for c in rows]), np.array(ref))
        out.append((body, slice(start, start + len(rows)), s))
        start += len(rows)
    return out


def channel_matrix(cfg: SystemConfig) -> Array:
    """Map, shape (n_ch, (N+1)*dof), from stacked true twists [ground, stage1 … stageN] (each at
    its reference point) to the true channel velocities (m/s)."""
    dof = cfg.plant.dof
    blocks = body_sensor_matrices(cfg)
    n_ch = blocks[-1][1].stop
    m = np.zeros((n_ch, len(blocks) * dof))
    for i, (_, sl, s) in enumerate(blocks):
        m[sl, i * dof:(i + 1) * dof] = s
    return m


class GeophoneArray:
    """Discrete geophones (Tustin at ``cfg.plant.rate_hz``) plus white self-noise per channel.

    Parameters
    ----------
    cfg : SystemConfig
    rng : numpy.random.Generator
        Source of the self-noise; consumed in blocks of :data:`NOISE_BLOCK` per channel set, so
        the readings depend only on the Generator's seed and the inputs.
    """

    def __init__(self, cfg: SystemConfig, rng: np.random.Generator) -> None:
        self.channels = channel_layout(cfg)
        self.channel_names = [c.name for c in self.channels]
        n = len(self.channels)
        fs = cfg.plant.rate_hz
        self._filter = SosFilter(to_sos(geophone_tf(cfg.sensors), fs), n)
        #: per-sample noise standard deviation, m/s: one-sided ASD over the band 0..fs/2
        self.noise_std = float(cfg.sensors.noise_asd) * math.sqrt(fs / 2.0)
        self._rng = rng
        self._noise = np.zeros((NOISE_BLOCK, n))
        self._k = NOISE_BLOCK  # forces a draw on the first step

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    @property
    def filter(self) -> SosFilter:
        """The geophone dynamics every channel runs (one channel per geophone)."""
        return self._filter

    def reset(self) -> None:
        """Zero the geophone states (the noise stream continues)."""
        self._filter.reset()

    def step(self, true_channel_velocity: ArrayLike) -> Array:
        """One sample: true channel velocities (n_ch,) m/s -> readings (n_ch,) m/s."""
        y = self._filter.step(true_channel_velocity)
        if self.noise_std > 0.0:
            if self._k == NOISE_BLOCK:
                self._noise = self._rng.standard_normal((NOISE_BLOCK, len(self.channels)))
                self._noise *= self.noise_std
                self._k = 0
            y += self._noise[self._k]
            self._k += 1
        return y

    def noise_block(self, n: int) -> Array:
        """The self-noise the next ``n`` calls of :meth:`step` would add, shape (n, n_ch) m/s,
        consuming the stream exactly as they would (all zeros and no draw when the noise is 0)."""
        out = np.zeros((n, len(self.channels)))
        if self.noise_std <= 0.0:
            return out
        i = 0
        while i < n:
            if self._k == NOISE_BLOCK:
                self._noise = self._rng.standard_normal((NOISE_BLOCK, len(self.channels)))
                self._noise *= self.noise_std
                self._k = 0
            m = min(n - i, NOISE_BLOCK - self._k)
            out[i:i + m] = self._noise[self._k:self._k + m]
            self._k += m
            i += m
        return out


__all__ = [
    "NOISE_BLOCK",
    "Channel",
    "GeophoneArray",
    "body_sensor_matrices",
    "channel_layout",
    "channel_matrix",
    "extension_tf",
    "geophone_tf",
]
