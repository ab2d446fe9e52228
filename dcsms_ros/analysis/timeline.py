"""What a bag's isolation table went through, window by window: the mode in force, the
supervisor's state, the ground's band-limited RMS and the peak actuator force; plus every
supervisor transition (issue 22).

Time axis: the header stamps of the ground velocity, s (the plant time for a batch bag and for
a graph running on sim time). A transition's time is the plant time written in its text
(``STATE MODE at T s: reason``, :attr:`~dcsms_ros.core.supervisor.Transition.label`), not its
bag time: a String has no header stamp, and the bag time of a graph on wall time is another
clock.

The ground BLRMS is the supervisor's own measure: the recorded ground velocity (decoupled, or
true when the bag has no decoupled one) through the instability trip's band-pass
(``control.trip_band_hz``, :class:`~dcsms_ros.core.trip.TripMonitor`, started in the steady
state of the first sample), RMS over each window; translations only (the bag reader keeps
x, y, z), with its relative standard deviation from the window's own equivalent degrees of
freedom (:func:`.uncertainty.envelope_dof`: a window's RMS as an estimate of a stationary
floor's). Samples are taken as uniformly spaced at the median rate (a drop shifts the filter by
one sample, not the window). The force is ``|applied|`` of each actuator over its limit
(:func:`~dcsms_ros.core.check.actuator_limits`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from dcsms_ros.analysis.reader import BagData
from dcsms_ros.analysis.series import AXIS_NAMES
from dcsms_ros.analysis.uncertainty import envelope_dof
from dcsms_ros.core.check import actuator_limits
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.trip import TripMonitor
from dcsms_ros.errors import DcsmsError

#: Default window of the timeline rows, s.
WINDOW_S = 1.0

_LABEL = re.compile(r"^(?P<state>[A-Z_]+) (?P<mode>\S+) at (?P<t>[-+0-9.eE]+) s: (?P<reason>.*)$",
                    re.DOTALL)


@dataclass(frozen=True)
class Event:
    """One supervisor transition read back from ``<ns>/supervisor/state``.

    Attributes
    ----------
    t_s : float
        Plant time of the transition's sample, s (the new mode runs from the next sample).
    state : str
        State entered (``RIDE_THROUGH`` ...).
    mode : str
        Mode label it runs (``FBC``, ``DFBC+FFC``).
    reason : str
        Why, as the supervisor wrote it.
    """

    t_s: float
    state: str
    mode: str
    reason: str


@dataclass(frozen=True)
class Row:
    """One window of the timeline.

    Attributes
    ----------
    t0_s, t1_s : float
        Window start (inclusive) and end (exclusive), s on the stamp axis.
    mode : str or None
        Mode in force at the window's end (None before the first ``/dcsms/mode``).
    state : str or None
        Supervisor state at the window's end (None before the first transition).
    changes : int
        Mode switches and supervisor transitions inside the window.
    ground_blrms_mps : tuple of float, shape (axes,)
        Ground velocity band RMS in the trip band per axis of :attr:`Timeline.axes`, m/s.
    ground_dof : float
        Equivalent degrees of freedom of the loudest axis' mean square over the window
        (:func:`.uncertainty.envelope_dof`), 1; nan when unknown.
    force_peak_n : float
        Largest ``|applied force|`` of any actuator in the window, N (nan without samples).
    force_fraction : float
        Largest ``|applied force| / limit`` of any actuator in the window, 1 (nan without).
    samples : int
        Ground samples in the window.
    """

    t0_s: float
    t1_s: float
    mode: str | None
    state: str | None
    changes: int
    ground_blrms_mps: tuple[float, ...]
    ground_dof: float
    force_peak_n: float
    force_fraction: float
    samples: int

    def loudest(self) -> float:
        """The loudest axis' ground band RMS, m/s (nan without samples)."""
        return max(self.ground_blrms_mps) if self.samples else float("nan")

    def ground_rel_std(self) -> float:
        """Relative standard deviation of :meth:`loudest` as an estimate of the floor's band
        RMS (a scaled chi-square mean square: ``1 / sqrt(2 nu)``), 1."""
        return 1.0 / float(np.sqrt(2.0 * self.ground_dof)) if self.ground_dof > 0 else float("nan")


@dataclass(frozen=True)
class Timeline:
    """A bag's timeline (see the module docstring).

    Attributes
    ----------
    window_s : float
        Row length, s.
    band_hz : tuple of float
        Band of the ground BLRMS (``control.trip_band_hz``), Hz.
    axes : tuple of str
        Axes of :attr:`Row.ground_blrms_mps`.
    limits_n : tuple of float
        Force limit per actuator column of the bag, N.
    rows : tuple of Row
    transitions : tuple of Event
        Every supervisor transition in time order.
    modes : tuple of (float, str)
        Every mode switch: stamp time (s) and label.
    warnings : tuple of str
        Texts on the supervisor topic that are not transitions.
    """

    window_s: float
    band_hz: tuple[float, float]
    axes: tuple[str, ...]
    limits_n: tuple[float, ...]
    rows: tuple[Row, ...]
    transitions: tuple[Event, ...]
    modes: tuple[tuple[float, str], ...]
    warnings: tuple[str, ...] = ()

    def condensed(self, edge: int = 1) -> list[Row]:
        """The rows worth reading: the first and last ``edge``, every row whose mode or state
        differs from the row before or that holds a change, and the loudest ground row."""
        keep = set(range(min(edge, len(self.rows)))) | set(
            range(max(0, len(self.rows) - edge), len(self.rows)))
        for i, r in enumerate(self.rows):
            prev = self.rows[i - 1] if i else None
            if r.changes or (prev is not None and (prev.mode, prev.state) != (r.mode, r.state)):
                keep.add(i)
        loud = [i for i, r in enumerate(self.rows) if r.samples]
        if loud:
            keep.add(max(loud, key=lambda i: self.rows[i].loudest()))
        return [self.rows[i] for i in sorted(keep)]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: every row and every transition (units in the key names)."""
        return {
            "window_s": self.window_s, "band_hz": list(self.band_hz), "axes": list(self.axes),
            "force_limits_n": list(self.limits_n),
            "transitions": [{"t_s": e.t_s, "state": e.state, "mode": e.mode,
                             "reason": e.reason} for e in self.transitions],
            "mode_switches": [{"t_s": t, "mode": m} for t, m in self.modes],
            "rows": [{"t0_s": r.t0_s, "t1_s": r.t1_s, "mode": r.mode, "state": r.state,
                      "changes": r.changes,
                      "ground_blrms_mps": dict(zip(self.axes, r.ground_blrms_mps, strict=True)),
                      "ground_dof": r.ground_dof, "ground_rel_std": r.ground_rel_std(),
                      "force_peak_n": r.force_peak_n, "force_fraction": r.force_fraction,
                      "samples": r.samples} for r in self.rows],
        }

    def lines(self) -> list[str]:
        """Plain-text lines: the transitions, then the condensed rows."""
        out = [(f"timeline ({self.window_s:g} s windows; ground BLRMS "
               f"{self.band_hz[0]:g}-{self.band_hz[1]:g} Hz, loudest of {''.join(self.axes)}):")]
        out += [f"  {e.t_s:9.4f} s  {e.state:<12} {e.mode:<9} {e.reason}"
                for e in self.transitions]
        out += [f"  {r.t0_s:8.2f}-{r.t1_s:<8.2f} {r.mode or '-':<9} {r.state or '-':<12} "
                f"ground {r.loudest():.3g} m/s +-{100.0 * r.ground_rel_std():.0f} %  "
                f"force {r.force_peak_n:.4g} N "
                f"({100.0 * r.force_fraction:.1f} % of limit)" for r in self.condensed()]
        return out


def parse_transition(text: str) -> Event | None:
    """An :class:`Event` from a ``<ns>/supervisor/state`` text, None if it is not one."""
    m = _LABEL.match(text.strip())
    if m is None:
        return None
    try:
        t = float(m["t"])
    except ValueError:
        return None
    return Event(t, m["state"], m["mode"], m["reason"])


def transitions(data: BagData) -> tuple[tuple[Event, ...], list[str]]:
    """The bag's supervisor transitions, in plant-time order, each once (a transient-local
    text recorded twice is one transition), and a warning per text that is not one."""
    seen: dict[str, Event] = {}
    bad = []
    for _, text in data.states:
        ev = parse_transition(text)
        if ev is None:
            bad.append(f"{data.path}: supervisor/state {text!r} is not 'STATE MODE at T s: "
                       "reason'; left out of the timeline")
        elif text not in seen:
            seen[text] = ev
    return tuple(sorted(seen.values(), key=lambda e: e.t_s)), bad


def _limits(cfg: SystemConfig, columns: tuple[str, ...]) -> tuple[float, ...]:
    """Limit (N) of each applied-force column: by actuator name, else by position."""
    names, lim = actuator_limits(cfg)
    by_name = dict(zip(names, lim.tolist(), strict=True))
    if all(c in by_name for c in columns):
        return tuple(by_name[c] for c in columns)
    if len(columns) == len(names):
        return tuple(lim.tolist())
    return tuple(cfg.actuators.force_limit_n for _ in columns)


def _at(times: list[float], values: list[str], t: float) -> str | None:
    """The value of the last entry with time < ``t`` (None before the first)."""
    i = int(np.searchsorted(np.asarray(times), t, side="left"))
    return values[i - 1] if i else None


def build(data: BagData, cfg: SystemConfig, window_s: float = WINDOW_S) -> Timeline | None:
    """The timeline of one read bag, or None when it has nothing to show (no supervisor
    transition and no mode switch after the first mode).

    Parameters
    ----------
    data : BagData
        A bag read by :func:`.reader.read_bag`.
    cfg : SystemConfig
        The run's configuration (``control.trip_band_hz``, the force limits).
    window_s : float
        Row length, s (> 0).

    Raises
    ------
    DcsmsError
        If ``window_s`` is not positive.
    """
    if not window_s > 0.0:
        raise DcsmsError(f"timeline window {window_s:g} s: must be > 0")
    events, bad = transitions(data)
    if not events and len(data.modes) < 2:
        return None
    ground = data.bodies.get("ground")
    if ground is None:
        ground = next(iter(data.bodies.values()))  # no ground topic: nothing better to show
    st = ground.stamp_ns
    axes = ("z",) if cfg.plant.dof == 1 else AXIS_NAMES
    cols = [AXIS_NAMES.index(a) for a in axes]
    modes = tuple((ev.stamp_ns * 1e-9, ev.label) for ev in data.modes)
    applied = data.applied
    limits = (_limits(cfg, applied.columns) if applied is not None and applied.values.size
              else ())
    if st.size < 2:
        return Timeline(window_s, cfg.control.trip_band_hz, axes, limits, (), events, modes,
                        tuple(bad))
    fs = 1e9 / float(np.median(np.diff(st)))
    mon = TripMonitor(cfg.control, fs, len(cols))
    lo, hi = cfg.control.trip_band_hz
    width = min(hi, fs / 2.0) - max(lo, 0.0)
    t0 = int(st[0])
    w_ns = int(round(window_s * 1e9))
    edges = np.arange(t0, int(st[-1]) + w_ns, w_ns, dtype=np.int64)
    if edges[-1] <= st[-1]:
        edges = np.append(edges, edges[-1] + w_ns)
    gi = np.searchsorted(st, edges)
    fi = np.searchsorted(applied.stamp_ns, edges) if limits and applied is not None else None
    lim = np.asarray(limits)
    m_t, m_l = [t for t, _ in modes], [lab for _, lab in modes]
    e_t, e_s = [e.t_s for e in events], [e.state for e in events]
    changes = np.asarray(m_t[1:] + e_t)
    rows = []
    for i in range(edges.size - 1):
        a, b = edges[i] * 1e-9, edges[i + 1] * 1e-9
        # the filter runs window by window with its state carried: one float64 window at a time
        y = mon.filter(ground.values[gi[i]:gi[i + 1]][:, cols])
        blrms = (tuple(np.sqrt(np.mean(y * y, axis=0)).tolist()) if y.shape[0]
                 else tuple(float("nan") for _ in cols))
        dof = envelope_dof(y[:, int(np.argmax(blrms))], fs, width) if y.shape[0] else np.nan
        peak = frac = float("nan")
        if fi is not None and applied is not None and fi[i + 1] > fi[i]:
            f = np.abs(applied.values[fi[i]:fi[i + 1]].astype(np.float64)).max(axis=0)
            peak, frac = float(f.max()), float((f / lim).max())
        rows.append(Row(a, b, _at(m_t, m_l, b), _at(e_t, e_s, b),
                        int(np.count_nonzero((changes >= a) & (changes < b))), blrms,
                        float(dof), peak, frac, int(gi[i + 1] - gi[i])))
    return Timeline(window_s, cfg.control.trip_band_hz, axes, limits, tuple(rows), events,
                    modes, tuple(bad))


__all__ = ["WINDOW_S", "Event", "Row", "Timeline", "build", "parse_transition", "transitions"]
