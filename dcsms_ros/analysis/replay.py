"""Ground excitation from a recorded bag: a measured floor velocity replayed into the plant.

:func:`load_ground` reads a ``geometry_msgs/TwistStamped`` topic (default
``/dcsms/velocity/ground``, else ``/dcsms/truth/ground``), orders it by header stamp and
resamples it to the control rate; the (K, dof) result goes to
``simulate(..., ground=...)`` or the plant-simulator node's ``ground_from`` parameter
(:class:`~dcsms_ros.core.disturbance.Disturbances` replays it and loops with a warning).

Resampling, in two steps:

1. Linear interpolation onto a uniform grid at ``fs_grid = rate * down / up`` (the recorded
   median rate, rounded so that ``up/down`` is a ratio of small integers). For a recording with
   regular stamps at the same rate the grid *is* the stamps and the values pass unchanged; it
   only matters for jittery wall-clock stamps and fills dropped samples (a warning says how
   many).
2. :func:`.polyphase.resample_poly` (``scipy.signal.resample_poly`` on numpy alone, so the
   plant node need not import scipy.signal): a linear-phase Kaiser-window FIR at the lower
   of the two Nyquist frequencies. Downsampling thus removes content above the new Nyquist
   instead of aliasing it into the isolation band (a plain interpolation or decimation would
   fold it down), and upsampling is band-limited interpolation, without the sinc² droop and
   images of linear interpolation. ``padtype="line"`` keeps the edges free of the filter's
   start-up transient for a signal with an offset or trend. Equal rates skip this step
   (bit-exact replay of a bag recorded at the control rate).
"""

from __future__ import annotations

import warnings
from fractions import Fraction
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.polyphase import resample_poly
from dcsms_ros.core import topics
from dcsms_ros.errors import BagError

Array = NDArray[np.float64]
#: Topics tried in order when none is given.
DEFAULT_TOPICS = (topics.velocity_topic("ground"), topics.truth_topic("ground"))
#: Largest ``up`` or ``down`` of the rational rate ratio.
MAX_RATIO_TERM = 1000


def parse_ground_spec(spec: str) -> tuple[Path, str | None]:
    """Split ``BAG[:TOPIC]`` (the topic starts with ``/``) into the bag path and topic."""
    head, sep, tail = spec.rpartition(":")
    if sep and head and tail.startswith("/"):
        return Path(head), tail
    return Path(spec), None


def read_twists(bag: str | Path, topic: str | None = None) -> tuple[str, np.ndarray, Array]:
    """Read one TwistStamped topic of a bag.

    Returns
    -------
    topic : str
        The topic read (the first of :data:`DEFAULT_TOPICS` present when ``topic`` is None).
    stamp_ns : ndarray of int64, shape (K,)
        Header stamps, ns, in bag order.
    values : ndarray, shape (K, 6)
        Twists ``[vx vy vz wx wy wz]`` (m/s, rad/s).

    Raises
    ------
    BagError
        Missing or unreadable bag, topic absent or not TwistStamped; names the bag.
    """
    p = Path(bag)
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    try:
        with Reader(p) as reader:
            conns = {c.topic: c for c in reader.connections}
            name = topic or next((t for t in DEFAULT_TOPICS if t in conns), DEFAULT_TOPICS[0])
            conn = conns.get(name)
            if conn is None:
                twists = sorted(t for t, c in conns.items() if c.msgtype == cdr.TWIST_STAMPED)
                raise BagError(f"{p}: no topic {name} (TwistStamped topics: "
                               f"{', '.join(twists) or 'none'})")
            if conn.msgtype != cdr.TWIST_STAMPED:
                raise BagError(f"{p}: {name} is {conn.msgtype}, expected {cdr.TWIST_STAMPED}")
            raw = [bytes(d) for _, _, d in reader.messages(connections=[conn])]
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags/mcap/sqlite raise many types
        raise BagError(f"{p}: cannot read bag: {type(exc).__name__}: {exc}") from None
    batch = cdr.decode_batch(cdr.TWIST_STAMPED, raw)
    return name, batch.stamp_ns, batch.fields["twist"]


def rate_ratio(fs_in: float, fs_out: float) -> tuple[int, int]:
    """``(up, down)`` with ``fs_out / fs_in ~= up / down``, both <= :data:`MAX_RATIO_TERM`."""
    fr = Fraction(fs_out / fs_in).limit_denominator(MAX_RATIO_TERM)
    if fr.numerator == 0 or fr.numerator > MAX_RATIO_TERM:
        raise BagError(f"cannot resample {fs_in:g} Hz to {fs_out:g} Hz (ratio out of range)")
    return fr.numerator, fr.denominator


def resample(stamp_ns: np.ndarray, values: Array, rate_hz: float) -> Array:
    """Resample irregularly stamped samples to ``rate_hz`` (see the module notes).

    Parameters
    ----------
    stamp_ns : array of int, shape (K,)
        Sample times, ns (any order; duplicates are dropped).
    values : ndarray, shape (K, n)
    rate_hz : float
        Output rate, Hz.

    Returns
    -------
    ndarray, shape (M, n)
        Samples at ``t0 + m / rate_hz``, t0 = the first stamp.
    """
    t, idx = np.unique(np.asarray(stamp_ns, dtype=np.int64), return_index=True)
    x = np.asarray(values, dtype=np.float64)[idx]
    if t.size < 2:
        raise BagError(f"need at least 2 samples to resample, got {t.size}")
    dt_in = float(np.median(np.diff(t)))
    up, down = rate_ratio(1e9 / dt_in, rate_hz)
    dt_grid = 1e9 * up / (down * rate_hz)  # ns; equals dt_in unless the ratio was rounded
    n_grid = int(np.floor((t[-1] - t[0]) / dt_grid + 1e-6)) + 1
    rel = (t - t[0]).astype(np.float64)
    grid = np.arange(n_grid) * dt_grid
    if n_grid == t.size and np.allclose(rel, grid, rtol=0.0, atol=1e-3 * dt_grid):
        xg = x  # already uniform: no interpolation at all
    else:
        missing = n_grid - t.size
        if missing > 0:
            warnings.warn(f"ground replay: {missing} sample(s) missing in the recording were "
                          "filled by linear interpolation", RuntimeWarning, stacklevel=2)
        xg = np.column_stack([np.interp(grid, rel, x[:, j]) for j in range(x.shape[1])])
    if up == down:
        return np.ascontiguousarray(xg)
    return resample_poly(xg, up, down)


def load_ground(bag: str | Path, topic: str | None, rate_hz: float, dof: int) -> Array:
    """Recorded ground velocity at the control rate, for ``simulate(..., ground=...)``.

    Parameters
    ----------
    bag : str or Path
        rosbag2 directory.
    topic : str or None
        TwistStamped topic; None tries ``/dcsms/velocity/ground`` then ``/dcsms/truth/ground``.
    rate_hz : float
        Control rate (``cfg.plant.rate_hz``), Hz.
    dof : int
        1 (keeps z) or 6 (keeps the whole twist).

    Returns
    -------
    ndarray, shape (K, dof)
        Ground twist, m/s (and rad/s).

    Raises
    ------
    BagError
        Bag or topic unusable; fewer than 2 samples; non-finite values.
    """
    if dof not in (1, 6):
        raise BagError(f"ground replay: dof must be 1 or 6, got {dof}")
    name, stamp, tw = read_twists(bag, topic)
    cols = tw[:, 2:3] if dof == 1 else tw
    if stamp.size < 2:
        raise BagError(f"{bag}: {name} has {stamp.size} message(s); need at least 2")
    if not np.all(np.isfinite(cols)):
        raise BagError(f"{bag}: {name} contains NaN or Inf")
    return resample(stamp, cols, rate_hz)


__all__ = ["DEFAULT_TOPICS", "load_ground", "parse_ground_spec", "rate_ratio", "read_twists",
           "resample"]
