"""Controller outputs held back a whole number of samples: the batch engine's model of a
real-time graph whose forces reach the plant late (checks :func:`.margins.delay_margins`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]


class DelayLines:
    """Per controller, a line of ``d`` samples: :meth:`shift` takes the output of sample k
    and returns the output of sample k - d (zero before the first).

    Parameters
    ----------
    delays : mapping of controller id to int
        Samples of delay per controller (>= 0; absent: none).
    known : iterable of str
        The controller ids the loop has (an unknown id is a configuration error).
    dof : int
        Length of a controller's output.
    """

    def __init__(self, delays: Mapping[str, int], known: set[str], dof: int) -> None:
        bad = sorted(set(delays) - known)
        if bad:
            raise ConfigError(f"delay: unknown controller(s) {', '.join(bad)} (known: "
                              f"{', '.join(sorted(known))})")
        for cid, d in delays.items():
            if int(d) != d or d < 0:
                raise ConfigError(f"delay: {cid} needs a whole number of samples >= 0, "
                                  f"got {d}")
        self._line = {cid: np.zeros((int(d), dof)) for cid, d in delays.items() if d > 0}
        self._at = dict.fromkeys(self._line, 0)

    def shift(self, cid: str, w: Array) -> Array:
        """The output ``cid`` gave ``d`` samples before ``w`` (``w`` itself without a line)."""
        line = self._line.get(cid)
        if line is None:
            return w
        i = self._at[cid]
        out = line[i].copy()
        line[i] = w
        self._at[cid] = (i + 1) % line.shape[0]
        return out


__all__ = ["DelayLines"]
