"""Supervisor: rides through ground bursts, re-engages after a trip, latches a loop that keeps
growing. A plain deterministic state machine stepped at the trip checkpoints (:mod:`.trip`,
every :data:`~.trip.CHECK_PERIOD_S` of plant time), so it costs the per-sample path nothing.

States (``docs/reliability.md`` draws them)::

    ENGAGED(user mode) --loud floor / force near limit / disturbance trip--> RIDE_THROUGH
    ENGAGED, RIDE_THROUGH, RECOVERING --growing loop--> TRIPPED (Passive)
    RIDE_THROUGH --quiet for recover_after_s--> RECOVERING (user mode, faded in)
    RECOVERING --settled for settle_s--> ENGAGED;  --loud again--> RIDE_THROUGH
    TRIPPED --hold (x backoff per attempt), quiet, model stable--> RECOVERING
    TRIPPED --more than max_attempts trips, no clean attempts_window_s between--> LATCHED
    LATCHED --reset()--> ENGAGED(Passive)

Disturbance or instability: a stage band RMS above the trip threshold is an instability when
the floor is quiet (nothing outside the loop explains it), when it is more than
``excess_ratio`` x what the loop model predicts for the measured ground (``band_gain``), or when
it grows faster than the ground by more than ``growth_per_s`` (an unstable loop grows
exponentially, a burst moves stage and ground together). Otherwise the supervisor rides
through. A mode the model calls unstable is never re-engaged (``stable`` tells it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import ControlConfig, SupervisorConfig
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.core.trip import CHECK_PERIOD_S

Array = NDArray[np.float64]


class State(Enum):
    """Supervisor states (the value is the label on ``<ns>/supervisor/state``)."""

    ENGAGED = "ENGAGED"
    RIDE_THROUGH = "RIDE_THROUGH"
    RECOVERING = "RECOVERING"
    TRIPPED = "TRIPPED"
    LATCHED = "LATCHED"


#: The labels of the states in which a trip holds the table Passive (an excitation stops).
TRIPPED_STATES = frozenset({State.TRIPPED.value, State.LATCHED.value})


_CFG = SupervisorConfig()
_RIDE_MODE = parse_mode(_CFG.ride_mode)


@dataclass(frozen=True)
class SupervisorSettings:
    """Thresholds and times of the supervisor (SI units).

    Attributes
    ----------
    enabled : bool
        False: a trip latches Passive at once (the behaviour without a supervisor).
    ride_mode : Mode
        The calmer mode of RIDE_THROUGH. Default FBC: velocity feedback alone is collocated
        damping, it keeps the suspension resonances damped while the floor is loud, and it
        does not push the floor's own motion through the feedforward path (FFC's force grows
        with the ground amplitude and saturates first); Passive would let the resonances ring.
    trip_rms_mps : float
        Stage band RMS above which a checkpoint is judged (the trip threshold), m/s.
    ride_ground_mps : float
        Ground band RMS that enters RIDE_THROUGH before a trip, m/s.
    ride_force_ratio : float
        Peak actuator force over its limit that enters RIDE_THROUGH, 1.
    quiet_fraction : float
        Quiet means the ground and the force below this fraction of their entry thresholds and
        the stage below it of ``trip_rms_mps`` (hysteresis), 1.
    recover_after_s : float
        Quiet time before the user's mode is re-engaged, s.
    settle_s : float
        Time RECOVERING lasts (the fade plus one trip window), s.
    excess_ratio : float
        Stage RMS over the floor's prediction above which a trip is an instability, 1.
    growth_per_s : float
        Growth rate of the stage RMS beyond the ground's above which a trip is an instability,
        1/s (``d ln rms / dt`` over ``growth_span`` checkpoints).
    floor_memory_s : float
        The floor that explains a stage RMS is the loudest of the last ``floor_memory_s``: the
        stage rings down through its resonances after the floor has calmed (measured: 4.2x the
        current floor's prediction 0.2 s after issue 22's burst), s.
    growth_span : int
        Checkpoints over which the growth is measured.
    hold_s : float
        Passive hold after the first trip, s; multiplied by ``backoff`` per further attempt.
    backoff : float
        Hold multiplier per attempt, 1.
    max_attempts : int
        Automatic re-engagements; one more trip latches, unless the mode ran clean (ENGAGED,
        no trip) for ``attempts_window_s`` in between.
    attempts_window_s : float
        A clean run this long forgives the trips before it, s.
    """

    # the defaults are the configuration's (one home: core/config.py, the schema's defaults)
    enabled: bool = _CFG.enabled
    ride_mode: Mode = _RIDE_MODE
    trip_rms_mps: float = ControlConfig.trip_rms_mps
    ride_ground_mps: float = _CFG.ride_ground_mps
    ride_force_ratio: float = _CFG.ride_force_ratio
    quiet_fraction: float = _CFG.quiet_fraction
    recover_after_s: float = _CFG.recover_after_s
    settle_s: float = _CFG.settle_s
    excess_ratio: float = _CFG.excess_ratio
    growth_per_s: float = _CFG.growth_per_s
    floor_memory_s: float = _CFG.floor_memory_s
    growth_span: int = 4
    hold_s: float = _CFG.hold_s
    backoff: float = _CFG.backoff
    max_attempts: int = _CFG.max_attempts
    attempts_window_s: float = _CFG.attempts_window_s


@dataclass(frozen=True)
class Checkpoint:
    """What the supervisor sees at one checkpoint.

    Attributes
    ----------
    sample : int
        The checkpoint's last sample k (a new mode runs from k + 1).
    t_s : float
        Plant time of sample k, s.
    stage_rms : ndarray, shape (N, dof)
        Band RMS of each stage's velocity over the trip window, m/s.
    ground_rms : ndarray, shape (dof,)
        Band RMS of the ground velocity over the same window, m/s.
    force_ratio : float
        Peak ``|force| / limit`` of any actuator over the window, 1.
    """

    sample: int
    t_s: float
    stage_rms: Array
    ground_rms: Array
    force_ratio: float


@dataclass(frozen=True)
class Transition:
    """A change of state or mode at ``sample`` (effective from ``sample + 1``)."""

    sample: int
    t_s: float
    state: State
    mode: Mode
    reason: str

    @property
    def label(self) -> str:
        """``STATE MODE at T s: reason``, the text of ``<ns>/supervisor/state``; T is the plant
        time of ``sample`` (a String has no stamp, and a bag's receive time is wall time)."""
        return f"{self.state.value} {self.mode.label} at {self.t_s:.4f} s: {self.reason}"


@dataclass
class _History:
    log_rel: list[float] = field(default_factory=list)  # ln(stage RMS / ground RMS)
    trips: list[float] = field(default_factory=list)  # times of the trips, s
    ground: list[float] = field(default_factory=list)  # loudest ground axis per checkpoint


class Supervisor:
    """The state machine of one table.

    Parameters
    ----------
    settings : SupervisorSettings
    mode : Mode
        The user's starting mode.
    band_gain : mapping Mode -> ndarray, shape (N, dof), optional
        Stage band RMS per unit ground band RMS (every ground axis as loud) that the model
        predicts in each mode (1; :func:`~dcsms_ros.core.floor.floor_gain`); a mode not in
        it (or None) is judged by the floor level and growth alone.
    stable : callable, optional
        ``stable(mode)`` is the model's verdict; default: every mode is stable.
    """

    def __init__(self, settings: SupervisorSettings, mode: Mode,
                 band_gain: Mapping[Mode, Array] | None = None,
                 stable: Callable[[Mode], bool] | None = None) -> None:
        self.s = settings
        self.user_mode = mode
        self.mode = mode
        self.state = State.ENGAGED
        self.band_gain: Mapping[Mode, Array] = band_gain if band_gain is not None else {}
        self.stable = stable or (lambda m: True)
        self.since = 0.0  # time the current state began, s
        self.quiet_since: float | None = None
        self.hist = _History()
        self.transitions: list[Transition] = []
        self.reason = ""

    # -- user requests -------------------------------------------------------------------
    def request(self, mode: Mode, sample: int, t_s: float) -> str | None:
        """A user's ``set_mode``: None if accepted (the mode runs from ``sample + 1``), else
        the reason it is refused.

        Accepted in ENGAGED and RECOVERING. During RIDE_THROUGH only Passive or the ride mode
        (calmer, never worse) are accepted: a more active mode while the floor is loud is what
        the supervisor protects against; the refusal says why and when. During TRIPPED only
        Passive (after an instability the ride mode may be what grew). LATCHED accepts
        nothing: ``reset_trip`` first.
        """
        refused = self.refusal(mode)
        if refused is not None:
            return refused
        self.user_mode = mode
        self._go(State.ENGAGED, mode, sample, t_s, f"user set {mode.label}")
        self.hist.trips.clear()
        return None

    def refusal(self, mode: Mode) -> str | None:
        """Why :meth:`request` would refuse ``mode`` now (None: it would accept); changes
        nothing, so a node can ask before it switches its controllers."""
        if self.state is State.LATCHED:
            return f"supervisor LATCHED ({self.reason}); call reset_trip first"
        if self.state is State.TRIPPED and mode is not Mode.PASSIVE:
            # after an instability even the ride mode may be what grew: only Passive
            return (f"supervisor TRIPPED ({self.reason}); {mode.label} is refused until the "
                    f"supervisor re-engages or reset_trip (Passive is accepted)")
        if self.state is State.RIDE_THROUGH and mode not in (Mode.PASSIVE, self.s.ride_mode):
            return (f"supervisor RIDE_THROUGH ({self.reason}); {mode.label} is refused "
                    f"until the floor has been quiet for {self.s.recover_after_s:g} s "
                    f"(Passive or {self.s.ride_mode.label} are accepted)")
        return None

    def reset(self, sample: int, t_s: float) -> None:
        """``reset_trip``: clears TRIPPED or LATCHED; the table stays Passive (ENGAGED)."""
        self.user_mode = Mode.PASSIVE
        self.hist = _History()
        self._go(State.ENGAGED, Mode.PASSIVE, sample, t_s, "reset_trip")

    # -- the checkpoint step ---------------------------------------------------------------
    def step(self, cp: Checkpoint) -> Transition | None:
        """Judge one checkpoint; the transition it causes (the mode runs from
        ``cp.sample + 1``), or None."""
        stage = float(np.max(cp.stage_rms))
        self.hist.log_rel.append(math.log(max(stage, 1e-300))
                                 - math.log(max(float(np.max(cp.ground_rms)), 1e-300)))
        del self.hist.log_rel[:-(self.s.growth_span + 1)]
        self.hist.ground.append(float(np.max(cp.ground_rms)))
        del self.hist.ground[:-max(1, int(round(self.s.floor_memory_s / CHECK_PERIOD_S)))]
        if self.state is State.LATCHED:
            return None
        # the user's Passive: nothing to ride through, but a motion the floor does not explain
        # (an excitation, a fault) still trips, which stops an excitation as the trip did
        passive = self.state is State.ENGAGED and self.mode is Mode.PASSIVE
        loud = self._loud(cp)
        if stage > self.s.trip_rms_mps and self.state is not State.TRIPPED:
            why = self._instability(cp, stage)
            if why is not None or not self.s.enabled:
                return self._trip(cp, why or f"stage band RMS {stage:.3g} m/s above "
                                  f"{self.s.trip_rms_mps:g} m/s")
            loud = loud or f"stage band RMS {stage:.3g} m/s explained by the floor"
        if passive:
            return None
        quiet = self._quiet(cp, stage)
        self.quiet_since = (self.quiet_since if self.quiet_since is not None else cp.t_s) \
            if quiet else None
        quiet_for = cp.t_s - self.quiet_since if self.quiet_since is not None else 0.0
        if not self.s.enabled:
            return None
        if self.state in (State.ENGAGED, State.RECOVERING) and loud:
            if self.mode is self.s.ride_mode and self.state is State.ENGAGED:
                return None
            return self._go(State.RIDE_THROUGH, self.s.ride_mode, cp.sample, cp.t_s, loud)
        if self.state is State.RIDE_THROUGH and quiet_for >= self.s.recover_after_s:
            return self._reengage(cp, f"quiet for {quiet_for:.2f} s")
        if self.state is State.RECOVERING and cp.t_s - self.since >= self.s.settle_s:
            return self._go(State.ENGAGED, self.mode, cp.sample, cp.t_s, "settled")
        if self.state is State.TRIPPED:
            hold = self.s.hold_s * self.s.backoff ** (len(self.hist.trips) - 1)
            if cp.t_s - self.since >= hold and quiet_for >= min(hold, self.s.settle_s):
                return self._reengage(cp, f"held Passive {cp.t_s - self.since:.2f} s "
                                      f"(attempt {len(self.hist.trips)} of "
                                      f"{self.s.max_attempts})")
        return None

    # -- judgements ----------------------------------------------------------------------
    def _excess(self, cp: Checkpoint) -> float:
        """Stage RMS over the floor's prediction in the running mode (worst channel, 1); 0
        with no model gain for it."""
        gain = self.band_gain.get(self.mode)
        if gain is None:
            return 0.0
        floor = gain * max(self.hist.ground)  # every ground axis as loud as the loudest
        return float(np.max(np.asarray(cp.stage_rms) / (floor + 1e-15)))

    def _instability(self, cp: Checkpoint, stage: float) -> str | None:
        """The reason a stage RMS above the trip threshold is an instability, or None for a
        disturbance the floor explains."""
        ground = max(self.hist.ground)
        if ground < self.s.ride_ground_mps and cp.force_ratio <= self.s.ride_force_ratio:
            return (f"stage band RMS {stage:.3g} m/s above {self.s.trip_rms_mps:g} m/s on a "
                    f"quiet floor (ground {ground:.3g} m/s)")
        excess = self._excess(cp)
        if excess > self.s.excess_ratio:
            return (f"stage band RMS {stage:.3g} m/s is {excess:.3g}x what the floor "
                    f"explains (limit {self.s.excess_ratio:g}x)")
        h = self.hist.log_rel
        # growth is the fallback without a model gain: at a burst's onset the stage lags the
        # floor through its resonances and grows faster than the ground for a few checkpoints
        # (measured: 6.3 /s on table1 DFBC+FFC), where the model's excess stays near 1
        if self.band_gain.get(self.mode) is None and len(h) > self.s.growth_span:
            rate = (h[-1] - h[-1 - self.s.growth_span]) / (self.s.growth_span * CHECK_PERIOD_S)
            if rate > self.s.growth_per_s:
                return (f"growing loop: stage band RMS {stage:.3g} m/s growing {rate:.3g} /s "
                        f"faster than the floor (limit {self.s.growth_per_s:g} /s)")
        return None

    def _loud(self, cp: Checkpoint) -> str:
        g = float(np.max(cp.ground_rms))
        if g > self.s.ride_ground_mps:
            return f"ground band RMS {g:.3g} m/s above {self.s.ride_ground_mps:g} m/s"
        if cp.force_ratio > self.s.ride_force_ratio:
            return (f"actuator force at {cp.force_ratio:.2f} of its limit (above "
                    f"{self.s.ride_force_ratio:g})")
        return ""

    def _quiet(self, cp: Checkpoint, stage: float) -> bool:
        q = self.s.quiet_fraction
        return (float(np.max(cp.ground_rms)) < q * self.s.ride_ground_mps
                and cp.force_ratio < q * self.s.ride_force_ratio
                and stage < q * self.s.trip_rms_mps)

    # -- actions -------------------------------------------------------------------------
    def _trip(self, cp: Checkpoint, why: str) -> Transition:
        # trips are forgiven only after the mode ran clean for attempts_window_s: a sliding
        # window forgave a slow loop for ever (TEM DFBC trips every ~50 s, its Passive
        # ring-down being that long)
        if self.state is State.ENGAGED and cp.t_s - self.since >= self.s.attempts_window_s:
            self.hist.trips.clear()
        self.hist.trips.append(cp.t_s)
        if not self.s.enabled:
            return self._go(State.LATCHED, Mode.PASSIVE, cp.sample, cp.t_s, why)
        if len(self.hist.trips) > self.s.max_attempts:
            return self._go(State.LATCHED, Mode.PASSIVE, cp.sample, cp.t_s,
                            f"{why}; {len(self.hist.trips)} trips without "
                            f"{self.s.attempts_window_s:g} s clean between, gave up")
        return self._go(State.TRIPPED, Mode.PASSIVE, cp.sample, cp.t_s, why)

    def _reengage(self, cp: Checkpoint, why: str) -> Transition | None:
        if not self.stable(self.user_mode):
            self.user_mode = Mode.PASSIVE
            return self._go(State.LATCHED, Mode.PASSIVE, cp.sample, cp.t_s,
                            "the model calls the user's mode unstable: not re-engaged")
        return self._go(State.RECOVERING, self.user_mode, cp.sample, cp.t_s, why)

    def _go(self, state: State, mode: Mode, sample: int, t_s: float, reason: str) -> Transition:
        self.state, self.mode, self.since, self.reason = state, mode, t_s, reason
        self.quiet_since = None
        tr = Transition(sample, t_s, state, mode, reason)
        self.transitions.append(tr)
        return tr

__all__ = ["TRIPPED_STATES", "Checkpoint", "State", "Supervisor",
           "SupervisorSettings", "Transition"]
