"""Split a bag's data into constant-mode segments (and, within a mode, into excited and quiet
parts) and align the bodies sample by sample."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from dcsms_ros.analysis.reader import BagData, ModeEvent
from dcsms_ros.analysis.series import TopicSeries
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.errors import ModeError

#: Default time dropped after each switch (s): longer than the default 0.5 s gain fade so the
#: segment holds only the steady mode, not the transition.
SETTLE_S = 1.0
#: Segments shorter than this (s, after settling) are reported but not analysed.
MIN_SEGMENT_S = 4.0
#: Zero-excitation gaps shorter than this (s) do not end an excited part (a sine passes 0).
EXCITE_GAP_S = 0.5


@dataclass
class Segment:
    """A time window of one mode, on the header-stamp axis.

    Attributes
    ----------
    label : str
        Mode label as recorded (``DFBC+FFC``) or ``unknown``.
    mode : Mode or None
        Parsed label (None if it is not one of the six modes).
    t0_ns, t1_ns : int
        Window [t0, t1) in ns, after dropping the settle time.
    switch_ns : int
        When the mode was entered (ns).
    excited : bool
        True when an excitation (``/dcsms/force/excitation``) is on throughout.
    """

    label: str
    mode: Mode | None
    t0_ns: int
    t1_ns: int
    switch_ns: int
    excited: bool = False

    @property
    def duration_s(self) -> float:
        return (self.t1_ns - self.t0_ns) * 1e-9


@dataclass
class Aligned:
    """Samples common to every body within a segment.

    Attributes
    ----------
    stamp_ns : ndarray of int64, shape (K,)
    bodies : dict of str to ndarray of float32, shape (K, 3)
        Velocity x, y, z (m/s) of each body.
    fs : float
        Sample rate (Hz) from the median stamp step.
    missing : int
        Samples missing from the uniform grid (drops, gaps) between first and last stamp.
    excitation : ndarray of float32, shape (K, 6), or None
        Excitation wrench x y z rx ry rz (N, N*m) of an excited segment on the same samples.
    """

    stamp_ns: np.ndarray
    bodies: dict[str, np.ndarray]
    fs: float
    missing: int
    excitation: np.ndarray | None = None


def _parse(label: str) -> Mode | None:
    try:
        return parse_mode(label)
    except ModeError:
        return None


def split_segments(modes: list[ModeEvent], t_first_ns: int, t_last_ns: int,
                   settle_s: float | Mapping[str, float] = SETTLE_S,
                   from_rest: bool = False) -> list[Segment]:
    """Constant-mode windows between the switches, each shortened by ``settle_s`` at its start.

    Parameters
    ----------
    modes : list of ModeEvent
        Switches in time order (header-stamp times).
    t_first_ns, t_last_ns : int
        First and last sample stamp of the data (ns).
    settle_s : float or mapping of mode label to float
        Time dropped after each switch (s), or after a switch into each mode (others:
        :data:`SETTLE_S`); the very first segment is not shortened unless it starts with a
        switch inside the data or ``from_rest``.
    from_rest : bool
        The data start with the system at rest (a simulation): the first segment's response
        builds up as after a switch, and loses the settle time too.

    Returns
    -------
    list of Segment
        In time order; a bag without ``/dcsms/mode`` gives one ``unknown`` segment.
    """
    if not modes:
        return [Segment("unknown", None, t_first_ns, t_last_ns + 1, t_first_ns)]
    out = []
    for i, ev in enumerate(modes):
        settle = int(round(settle_for(settle_s, ev.label) * 1e9))
        start = ev.stamp_ns
        # The first label is often the latched mode recorded before any data: nothing switched
        # at the start of the data, so there is no transient to drop.
        t0 = start if (i == 0 and start <= t_first_ns and not from_rest) else \
            max(start, t_first_ns) + settle
        t1 = modes[i + 1].stamp_ns if i + 1 < len(modes) else t_last_ns + 1
        if t1 > t0:
            out.append(Segment(ev.label, _parse(ev.label), t0, t1, start))
    return out


def settle_for(settle_s: float | Mapping[str, float], label: str) -> float:
    """The settle time (s) after a switch into ``label`` (:func:`split_segments`)."""
    if isinstance(settle_s, Mapping):
        return float(settle_s.get(label, SETTLE_S))
    return float(settle_s)


def split_excited(segments: list[Segment], excitation: TopicSeries | None,
                  settle_s: float | Mapping[str, float] = SETTLE_S) -> list[Segment]:
    """Split each segment where an excitation starts or stops; the part after each such change
    loses ``settle_s`` (the response's transient), as after a mode switch.

    Parameters
    ----------
    segments : list of Segment
        From :func:`split_segments`.
    excitation : TopicSeries or None
        ``/dcsms/force/excitation``; a sample is excited when any component is non-zero, and
        zero gaps shorter than :data:`EXCITE_GAP_S` do not count.
    settle_s : float or mapping of mode label to float
        Time dropped after every start or stop (s), per mode as in :func:`split_segments`.
    """
    if excitation is None or excitation.stamp_ns.size == 0:
        return segments
    on = np.any(excitation.values != 0.0, axis=1)
    stamps = excitation.stamp_ns
    if not on.any():
        return segments
    # fill short gaps (zero crossings, single lost samples)
    gap = int(round(EXCITE_GAP_S * 1e9))
    idx = np.flatnonzero(on)
    short = np.flatnonzero((np.diff(idx) > 1) & (np.diff(stamps[idx]) < gap))
    for j in short:
        on[idx[j]:idx[j + 1]] = True
    change = np.flatnonzero(np.diff(on.astype(np.int8))) + 1
    edges = [(int(stamps[i]), bool(on[i])) for i in change]
    out = []
    for seg in segments:
        settle = int(round(settle_for(settle_s, seg.label) * 1e9))
        k = int(np.searchsorted(stamps, seg.t0_ns))
        state = bool(on[min(k, on.size - 1)]) if on.size else False
        t0 = seg.t0_ns
        for t_edge, new in edges:
            if t_edge <= seg.t0_ns:
                continue
            if t_edge >= seg.t1_ns:
                break
            if t_edge > t0:
                out.append(Segment(seg.label, seg.mode, t0, t_edge, seg.switch_ns, state))
            t0, state = t_edge + settle, new
        if seg.t1_ns > t0:
            out.append(Segment(seg.label, seg.mode, t0, seg.t1_ns, seg.switch_ns, state))
    return out


def align(data: BagData, seg: Segment) -> Aligned:
    """Samples of every body in ``seg`` that share one stamp (drops in one topic are removed
    from all, so cross-spectra compare the same instants); an excited segment adds the
    excitation to the topics aligned.

    The values stay float32 and, when every topic holds the same stamps (no drops: the usual
    case), are views into the bag's arrays: an hour-long segment costs no copy.
    """
    series = dict(data.bodies)
    if seg.excited and data.excitation is not None:
        series[_EXCITE] = data.excitation
    windows = {}
    for name, s in series.items():
        i0, i1 = np.searchsorted(s.stamp_ns, [seg.t0_ns, seg.t1_ns])
        windows[name] = (s, int(i0), int(i1))
    stamps = [s.stamp_ns[i0:i1] for s, i0, i1 in windows.values()]
    if all(st.size == stamps[0].size and np.array_equal(st, stamps[0]) for st in stamps[1:]):
        common = stamps[0]
        bodies = {name: s.values[i0:i1] for name, (s, i0, i1) in windows.items()}
    else:
        common = stamps[0]
        for st in stamps[1:]:
            common = np.intersect1d(common, st, assume_unique=True)
        bodies = {name: s.values[np.searchsorted(s.stamp_ns, common)]
                  for name, (s, _, _) in windows.items()}
    exc = bodies.pop(_EXCITE, None)
    if common.size < 2:
        return Aligned(common, bodies, 0.0, 0, exc)
    dt = float(np.median(np.diff(common)))
    expected = int(round((common[-1] - common[0]) / dt)) + 1
    return Aligned(common, bodies, 1e9 / dt, max(expected - common.size, 0), exc)


_EXCITE = "/excitation"  # a key no body has

__all__ = ["EXCITE_GAP_S", "MIN_SEGMENT_S", "SETTLE_S", "Aligned", "Segment", "align",
           "settle_for", "split_excited", "split_segments"]
