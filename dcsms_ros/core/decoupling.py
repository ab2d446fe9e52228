"""Sensor decoupling: raw geophone channels -> LF extension -> rigid-body twist per body."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.filters import to_sos
from dcsms_ros.core.sensors import body_sensor_matrices, channel_layout, extension_tf
from dcsms_ros.core.sosfilter import SosFilter

Array = NDArray[np.float64]


class Decoupler:
    """Turn raw channel velocities into one twist per body (ground, stage1 … stageN).

    Each channel first passes the low-frequency extension filter; each body's channels are
    then mapped through ``pinv(S_body)`` (1dof: identity) to the twist at its reference point.

    Parameters
    ----------
    cfg : SystemConfig

    Attributes
    ----------
    nonfinite : int
        Samples in which some body had a non-finite channel (that body's output was zero).
    """

    def __init__(self, cfg: SystemConfig) -> None:
        layout = channel_layout(cfg)
        self.channel_names: list[str] = [c.name for c in layout]
        self.dof = cfg.plant.dof
        bodies = body_sensor_matrices(cfg)
        self._blocks = [(sl, np.linalg.pinv(s)) for _, sl, s in bodies]
        self.body_names = [b for b, _, _ in bodies]
        n = len(layout)
        self._ext = SosFilter(to_sos(extension_tf(cfg.sensors), cfg.plant.rate_hz), n)
        self._out = np.zeros((len(self._blocks), self.dof))
        self.nonfinite = 0

    @property
    def n_channels(self) -> int:
        return len(self.channel_names)

    @property
    def extension(self) -> SosFilter:
        """The low-frequency extension filter, one channel per geophone."""
        return self._ext

    @property
    def blocks(self) -> list[tuple[slice, Array]]:
        """Per body: its slice of the channel vector and ``pinv(S)``, shape (dof, n_b)."""
        return [(sl, np.asarray(m, dtype=np.float64)) for sl, m in self._blocks]

    def reset(self) -> None:
        """Zero the extension filter states and the counter."""
        self._ext.reset()
        self.nonfinite = 0

    def step(self, raw: ArrayLike) -> Array:
        """One sample.

        Parameters
        ----------
        raw : array_like, shape (n_ch,)
            Raw channel velocities, m/s, in :func:`.sensors.channel_layout` order.

        Returns
        -------
        ndarray, shape (N+1, dof)
            Twists (m/s, rad/s) of ground, stage1 … stageN at their reference points; a new
            array. A body with any non-finite channel reads zero and its filter states hold.
        """
        x = np.asarray(raw, dtype=np.float64)
        if all(map(math.isfinite, x.tolist())):  # a few channels: cheaper than numpy's calls
            v = self._ext.step(x)
            bad = None
        else:
            finite = np.isfinite(x)
            # hold the bad channels' filter states so one NaN cannot poison them forever
            saved = self._ext.get_state()
            v = self._ext.step(np.where(finite, x, 0.0))
            bad = ~finite
            state = self._ext.get_state()
            state[:, :, bad] = saved[:, :, bad]
            self._ext.set_state(state)
        out = self._out
        for i, (sl, pinv) in enumerate(self._blocks):
            if bad is not None and bad[sl].any():
                out[i] = 0.0
                self.nonfinite += 1
            else:
                out[i] = pinv @ v[sl]
        return out.copy()


__all__ = ["Decoupler"]
