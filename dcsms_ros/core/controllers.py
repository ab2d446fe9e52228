"""Controller step objects: gain fader, actuator allocation, feedback and feedforward loops.

Each loop runs its discrete filters every sample, even while disabled, so that enabling it
fades in a warm filter instead of a cold start. Saturation uses conditional integration: a
sample whose forces clip restores the filter state from before that sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.filters import (
    IDENTITY_SECTION,
    TF,
    feedback_tf,
    feedforward_tf,
    to_sos,
)
from dcsms_ros.core.geometry import drive_matrix
from dcsms_ros.core.modes import ControllerId
from dcsms_ros.core.sosfilter import SosFilter, flat
from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]

#: Index of the vertical axis in a 6-vector; a 1dof body carries only this one.
Z_AXIS = 2


class Fader:
    """Linear gain ramp between 0 and 1.

    Parameters
    ----------
    fade_time_s : float
        Time for a full 0 -> 1 ramp, s; 0 switches instantly.
    dt : float
        Sample period, s.
    on : bool
        Initial state (value 1 if True, else 0).
    """

    def __init__(self, fade_time_s: float, dt: float, on: bool = False) -> None:
        # an integer step counter keeps the ramp exact and free of accumulated rounding
        self._n = max(0, int(round(fade_time_s / dt)))
        self._k = self._n if on else 0
        self._on = bool(on)
        self._value = 1.0 if on else 0.0

    @property
    def value(self) -> float:
        """Current gain in [0, 1]."""
        return self._value

    @property
    def target(self) -> bool:
        """True while ramping towards (or at) 1."""
        return self._on

    @property
    def steps(self) -> int:
        """Samples of a full 0 -> 1 ramp (0: instant switching)."""
        return self._n

    @property
    def count(self) -> int:
        """Samples into the ramp, 0 .. :attr:`steps`; the gain is ``count / steps``."""
        return self._k

    def set_target(self, on: bool) -> None:
        """Ramp towards 1 (True) or 0 (False) from the current value."""
        self._on = bool(on)

    def step(self) -> float:
        """Advance one sample and return the new gain."""
        if self._n == 0:
            self._value = 1.0 if self._on else 0.0
            return self._value
        if self._on and self._k < self._n:
            self._k += 1
        elif not self._on and self._k > 0:
            self._k -= 1
        self._value = self._k / self._n
        return self._value


class Allocator:
    """Actuators of one stage: drive matrix, pseudo-inverse allocation and force limit.

    Parameters
    ----------
    cfg : SystemConfig
    stage_index : int
        1-based stage number.

    Notes
    -----
    6dof: ``B = drive_matrix(actuators, stage.com)``, shape (6, n_act), limit per actuator
    ``force_limit_n``. 1dof: the vertical actuators are one lumped channel, ``B = [[1]]``,
    limit ``actuator_count * force_limit_n``.
    """

    def __init__(self, cfg: SystemConfig, stage_index: int) -> None:
        if not 1 <= stage_index <= cfg.plant.num_stages:
            raise ConfigError(f"{cfg.source}: stage {stage_index} does not exist "
                              f"(num_stages = {cfg.plant.num_stages})")
        st = cfg.plant.stages[stage_index - 1]
        if cfg.plant.dof == 1:
            self.b = np.ones((1, 1))
            self.limit = float(st.actuator_count * cfg.actuators.force_limit_n)
        else:
            self.b = drive_matrix(np.array(st.actuators.position),
                                  np.array(st.actuators.direction), np.array(st.com))
            self.limit = float(cfg.actuators.force_limit_n)
        self.pinv: Array = np.asarray(np.linalg.pinv(self.b), dtype=np.float64)
        # |forces_i| <= max_i sum_j |pinv_ij| * max_j |wrench_j|: a wrench no larger than this
        # in every component puts no actuator at its limit (margin for the rounding of the
        # product), so the allocation need not be computed to know that
        gain = float(np.abs(self.pinv).sum(axis=1).max()) if self.pinv.size else 0.0
        #: Largest wrench component (N, N*m) that cannot saturate an actuator.
        self.safe_wrench = self.limit / gain * (1.0 - 1e-9) if gain > 0.0 else math.inf

    @property
    def n_act(self) -> int:
        return int(self.b.shape[1])

    def forces(self, wrench: ArrayLike) -> Array:
        """Least-norm actuator forces (n_act,) N for a wrench (dof,) at the reference point."""
        return self.pinv @ np.asarray(wrench, dtype=np.float64)

    def clip(self, forces: ArrayLike) -> tuple[Array, int]:
        """Clip each force to +-limit; returns (clipped (n_act,), number of clipped actuators)."""
        f = np.asarray(forces, dtype=np.float64)
        lim = self.limit
        n = sum(abs(v) > lim for v in f.tolist())  # a few floats: faster than numpy's calls
        return (np.clip(f, -self.limit, self.limit).astype(np.float64) if n else f.copy()), n

    def wrench(self, forces: ArrayLike) -> Array:
        """Wrench (dof,) at the reference point produced by actuator forces (n_act,)."""
        return self.b @ np.asarray(forces, dtype=np.float64)


class _Loop:
    """Shared machinery: per-axis SOS filters, fader, allocation, anti-windup, fault counters."""

    def __init__(self, cfg: SystemConfig, stage_index: int, tfs: dict[int, TF],
                 enabled: bool, prewarp_hz: float = 0.0) -> None:
        self.dof = cfg.plant.dof
        self.stage_index = stage_index
        #: continuous compensator per active axis, keyed by index into the (dof,) vector
        self.tfs = tfs
        self._axes = np.array(sorted(tfs), dtype=np.intp)
        self.allocator = Allocator(cfg, stage_index)
        fs = cfg.plant.rate_hz
        sos = [to_sos(tfs[a], fs, prewarp_hz) for a in self._axes]
        n_sec = max((s.shape[0] for s in sos), default=1)
        # pad with pass-through sections so every axis stacks into one vectorised filter
        sos = [np.vstack([s] + [IDENTITY_SECTION[None, :]] * (n_sec - s.shape[0])) for s in sos]
        self._filter = SosFilter(np.array(sos) if sos else np.zeros((0, 1, 6)), len(sos))
        self._saved = self._filter.get_state()
        self._axes_list: list[int] = self._axes.tolist()
        self._scalar = self._filter.scalar  # read at every sample
        self._views()
        self.fader = Fader(cfg.control.fade_time_s, cfg.plant.dt, on=enabled)
        self.fader.set_target(enabled)
        self.saturations = 0
        self.nonfinite = 0
        self.last_saturated = 0

    def _views(self) -> None:
        self._state_flat = flat(self._filter.arrays.state)
        self._saved_flat = flat(self._saved)

    def __getstate__(self) -> dict[str, Any]:
        # views are not copied or pickled: a copy gets views of its own arrays
        return {k: v for k, v in self.__dict__.items() if k not in ("_state_flat", "_saved_flat")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._views()

    @property
    def enabled(self) -> bool:
        return self.fader.target

    @property
    def axes(self) -> NDArray[np.intp]:
        """Indices into the (dof,) twist of the axes this loop acts on, ascending."""
        return self._axes

    @property
    def filter(self) -> SosFilter:
        """The compensator sections, one channel per entry of :attr:`axes`."""
        return self._filter

    @property
    def saved_state(self) -> Array:
        """The filter state from before the current sample, which a saturated sample restores
        (conditional integration); shape as :meth:`SosFilter.get_state`, shared buffer."""
        return self._saved

    def enable(self, on: bool) -> None:
        """Fade the output in (True) or out (False) over ``control.fade_time_s``."""
        self.fader.set_target(on)

    def reset(self) -> None:
        """Zero the filter states and the counters (the fader keeps its value)."""
        self._filter.reset()
        self.saturations = 0
        self.nonfinite = 0
        self.last_saturated = 0

    def prime(self, twist: ArrayLike) -> None:
        """Start the filters in the steady state of a constant ``twist`` (dof,) (a controller
        joining a running plant; see :meth:`~dcsms_ros.core.sosfilter.SosFilter.prime`)."""
        x = np.asarray(twist, dtype=np.float64)
        if np.isfinite(x).all():
            self._filter.prime(x[self._axes])

    def step(self, twist: ArrayLike) -> Array:
        """One sample: measured twist (dof,) m/s, rad/s -> wrench (dof,) N, N*m on the stage.

        A non-finite input gives zero output and leaves the states untouched (``nonfinite``
        counts it). Forces beyond the actuator limit are clipped (``saturations`` counts the
        samples) and that sample's filter update is undone.
        """
        return np.array(self.step_floats(np.asarray(twist, dtype=np.float64).tolist()))

    def step_floats(self, x: Sequence[float]) -> list[float]:
        """:meth:`step` on Python floats: twist (dof,) -> wrench (dof,), the same operations
        and counters. A node's sample is a few floats from its message to its message: on
        floats end to end it makes no numpy call unless an actuator nears its limit."""
        # the same operations as the batch engine's compiled loop, so the same bits
        # (test_engine_fast holds it)
        fade = self.fader.step()
        if not all(map(math.isfinite, x)):
            self._count_rejected()
            return [0.0] * self.dof
        self._saved_flat[:] = self._state_flat  # get_state(saved) without the numpy call
        filt, axes = self._filter, self._axes_list
        u = list(map(x.__getitem__, axes))  # no comprehension frame (3.11)
        y = filt.step_floats(u) if self._scalar else filt.step(np.array(u)).tolist()
        wl = [0.0] * self.dof
        for a, ya in zip(axes, y, strict=True):
            wl[a] = -fade * ya
        self.last_saturated = 0
        if fade == 0.0 or max(map(abs, wl)) <= self.allocator.safe_wrench:
            return wl  # the usual sample: no actuator near its limit (the allocation costs 1.7 us)
        return self._allocated(np.array(wl)).tolist()

    def _count_rejected(self) -> None:
        self.nonfinite += 1
        self.last_saturated = 0

    def _rejected(self) -> Array:
        """A non-finite twist's answer: zero wrench, counted, the states untouched."""
        self._count_rejected()
        return np.zeros(self.dof)

    def _allocated(self, w: Array) -> Array:
        """Wrench ``w`` (dof,) of this sample's filter update, allocated: ``w`` itself when no
        actuator is beyond its limit, else the clipped forces' wrench with the update undone
        (conditional integration; ``saturations`` and ``last_saturated`` count it)."""
        clipped, n_sat = self.allocator.clip(self.allocator.forces(w))
        if n_sat == 0:
            return w
        self.saturations += 1
        self.last_saturated = n_sat
        self._filter.set_state(self._saved)
        return self.allocator.wrench(clipped)


def _axes(dof: int, axes6: range) -> list[tuple[int, int]]:
    """(index into the dof vector, index into 6-vectors) of the axes a body carries."""
    if dof == 1:
        return [(0, Z_AXIS)] if Z_AXIS in axes6 else []
    return [(a, a) for a in axes6]


class FeedbackLoop(_Loop):
    """Velocity feedback of stage ``stage_index`` (1-based): ``w = -fade * feedback_tf * v``.

    Parameters
    ----------
    cfg : SystemConfig
        Uses ``feedback[stage_index - 1]``, ``control.fade_time_s``, ``actuators``.
    stage_index : int
    enabled : bool
        Initial state; True starts at full gain without a fade.
    """

    def __init__(self, cfg: SystemConfig, stage_index: int, enabled: bool = False) -> None:
        if not 1 <= stage_index <= len(cfg.feedback):
            raise ConfigError(f"{cfg.source}: no feedback settings for stage {stage_index}")
        fb = cfg.feedback[stage_index - 1]
        tfs = {i: feedback_tf(fb, a) for i, a in _axes(cfg.plant.dof, range(6))
               if fb.gain[a] != 0.0}
        # prewarp at the notch so the discrete notch sits exactly where it was designed
        pw = fb.notch_hz if 0.0 < fb.notch_hz < cfg.plant.rate_hz / 2.0 else 0.0
        super().__init__(cfg, stage_index, tfs, enabled, pw)


def suspension_totals(cfg: SystemConfig, stage_index: int = 1) -> list[tuple[float, float]]:
    """(damping N*s/m, stiffness N/m) of a stage's suspension along x, y, z.

    1dof: the vertical values on every axis; 6dof: the sums over its mounts per axis.
    """
    st = cfg.plant.stages[stage_index - 1]
    if cfg.plant.dof == 1:
        return [(st.damping, st.stiffness)] * 3
    return [(sum(c[j] for c in st.mounts.damping), sum(k[j] for k in st.mounts.stiffness))
            for j in range(3)]


class FeedforwardLoop(_Loop):
    """Ground feedforward into the stage-1 actuators: ``w = -fade * feedforward_tf * v_b``.

    Each translational axis uses the stage-1 suspension totals of that axis
    (:func:`suspension_totals`); rotations get no feedforward.
    """

    def __init__(self, cfg: SystemConfig, enabled: bool = False) -> None:
        totals = suspension_totals(cfg, 1)
        ff = cfg.feedforward
        tfs = {i: feedforward_tf(ff, *totals[a]) for i, a in _axes(cfg.plant.dof, range(3))
               if ff.gain != 0.0 and (totals[a][0] != 0.0 or totals[a][1] != 0.0)}
        super().__init__(cfg, 1, tfs, enabled)


#: The classes :func:`make_controller` builds: (feedback, feedforward).
Kinds = tuple[type[FeedbackLoop], type[FeedforwardLoop]]


def make_controller(cfg: SystemConfig, controller_id: str, enabled: bool = False,
                    kinds: Kinds = (FeedbackLoop, FeedforwardLoop)
                    ) -> FeedbackLoop | FeedforwardLoop:
    """Build a controller from its id: ``fb_stage<i>`` (i = 1..N) or ``ff_stage1``, of the
    classes ``kinds`` (feedback, feedforward; :mod:`.compiledcontrol` has compiled ones).

    Raises
    ------
    ConfigError
        An id :meth:`~dcsms_ros.core.modes.ControllerId.parse` rejects, or a stage beyond N.
    """
    who = ControllerId.parse(controller_id)
    if not who.feedback:
        return kinds[1](cfg, enabled)
    if who.stage > cfg.plant.num_stages:
        raise ConfigError(f"{cfg.source}: {controller_id}: only {cfg.plant.num_stages} stages")
    return kinds[0](cfg, who.stage, enabled)


def retuned(old: FeedbackLoop | FeedforwardLoop, cfg: SystemConfig, controller_id: str,
            keep_fade: bool = True) -> FeedbackLoop | FeedforwardLoop:
    """``old`` rebuilt from a new tuning ``cfg``, keeping what state can be kept: the gain
    ramp (unless the fade time changed: ``keep_fade`` False), and with the same filter
    structure (a gain or corner tweak) the delay states, so the output continues instead of
    restarting from rest; the fault counters carry over."""
    new = make_controller(cfg, controller_id, enabled=old.enabled,
                          kinds=(type(old), FeedforwardLoop) if isinstance(old, FeedbackLoop)
                          else (FeedbackLoop, type(old)))
    if keep_fade:
        new.fader = old.fader
    so, sn = old.filter.get_state(), new.filter.get_state()
    if so.shape == sn.shape:
        new.filter.set_state(so)
    new.saturations, new.nonfinite = old.saturations, old.nonfinite
    return new


def actuator_limits(cfg: SystemConfig) -> tuple[list[str], Array]:
    """Every actuator's name (``stage<i>/a<j>``) and force limit (N), in input order."""
    names, lim = [], []
    for i, st in enumerate(cfg.plant.stages, 1):
        a = Allocator(cfg, i)
        names += [f"{st.name}/a{j}" for j in range(a.n_act)]
        lim += [a.limit] * a.n_act
    return names, np.asarray(lim)


__all__ = [
    "Allocator",
    "Fader",
    "FeedbackLoop",
    "FeedforwardLoop",
    "Kinds",
    "actuator_limits",
    "make_controller",
    "retuned",
    "suspension_totals",
]
