"""Batch closed-loop simulation without ROS.

It steps exactly the objects the nodes step — :class:`PlantSimulator` (plant node),
:class:`Decoupler` (sensor-decoupling node), the feedback and feedforward loops (controller nodes)
— in the order the lockstep graph does, so a lockstep graph with the same configuration and seed
reproduces :func:`simulate` sample for sample.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core import fastsim
from dcsms_ros.core.checkpoints import CheckpointFeed
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import make_controller
from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.core.delayline import DelayLines
from dcsms_ros.core.modes import ControllerId, Mode, controller_ids, enabled_controllers
from dcsms_ros.core.simresult import SimResult
from dcsms_ros.core.simulator import PlantSimulator, check_plant
from dcsms_ros.core.sosfilter import BlockFilter
from dcsms_ros.core.supervision import make_supervisor
from dcsms_ros.core.supervisor import State, Supervisor
from dcsms_ros.core.trip import Trip, TripChecker
from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]


def simulate(cfg: SystemConfig, mode: Mode, duration_s: float, seed: int | None = None,
             schedule: Sequence[tuple[float, Mode]] = (), ground: Array | None = None,
             progress: Callable[[float], None] | None = None,
             fast: bool | None = None, table: Array | None = None,
             trip: bool = True, excite: Array | None = None,
             plant: SystemConfig | None = None, allow_unstable: bool = False,
             delay: Mapping[str, int] | None = None) -> SimResult:
    """Run the closed loop for ``duration_s`` seconds.

    Parameters
    ----------
    cfg : SystemConfig
        The system and controller configuration.
    mode : Mode
        Mode at t = 0; its controllers start enabled at full gain (no fade), as a graph started
        with ``initial_mode`` does.
    duration_s : float
        Simulated time, s.
    seed : int, optional
        Seed of the disturbances and sensor noise (default ``cfg.disturbance.seed``).
    schedule : sequence of (time_s, Mode)
        Later mode switches; gains fade over ``cfg.control.fade_time_s``.
    ground : ndarray, shape (K, dof), optional
        Recorded ground velocity to replay instead of white noise (m/s).
    progress : callable, optional
        Called with the completed fraction every ~1 % of the run.
    fast : bool, optional
        True runs the same algorithm fused into one compiled loop (:mod:`.fastsim`, needs
        numba; identical results, ~50-100x faster); False steps the objects sample by sample
        as the nodes do. Default: fast when numba is available. A run that meets a non-finite
        value is redone on the object path, which owns the fault handling and counters.
    table : ndarray, shape (K, N, dof), optional
        Wrenches added to the table forces of the first K samples (N, N*m).
    trip : bool
        Run the instability trip (:mod:`.trip`) and, with ``supervisor.enabled``, the
        supervisor (:mod:`.supervisor`) as the mode-switch node does (default True).
    excite : ndarray, shape (K, N, dof), optional
        Excitation wrench per stage for the first K samples (N, N*m; :mod:`.excitation`),
        added to the controllers' wrenches before allocation and clipping; off from a trip on.
    plant : SystemConfig, optional
        The physical plant (masses, suspensions, geophones, disturbances) when it differs from
        ``cfg``, which then only sets up the controllers, the decoupling (its low-frequency
        extension) and the trip, as on a rig whose true parameters are not known exactly
        (:func:`.simulator.check_plant`).
    allow_unstable : bool
        The supervisor may re-engage a mode the model calls unstable (as ``allow_unstable``
        lets the mode-switch node run one).
    delay : mapping of controller id to int, optional
        Samples by which each listed controller's wrench reaches the plant late, as a slow
        real-time graph delivers it (:mod:`.delayline`; a what-if the lockstep graph does not
        run). Runs on the object path.
    """
    steps = int(round(duration_s * cfg.plant.rate_hz))
    args = (cfg, mode, seed, schedule, ground, table, trip)
    kw: dict[str, Any] = {"excite": excite, "plant": plant, "allow_unstable": allow_unstable,
                          "delay": delay}
    res = Simulation(*args, fast=fast, **kw).run(steps, progress)
    if res is None:
        res = Simulation(*args, fast=False, **kw).run(steps, progress)
    assert res is not None
    return res


class Simulation:
    """A closed-loop run that advances block by block (:meth:`run`); the blocks of one
    Simulation concatenate to what a single :func:`simulate` call returns.

    Parameters are those of :func:`simulate` (``schedule`` times are from t = 0 of the run);
    ``supervisor`` replaces the one ``cfg.supervisor`` describes (built when
    ``supervisor.enabled`` and ``trip``; without one a trip latches Passive).
    """

    def __init__(self, cfg: SystemConfig, mode: Mode, seed: int | None = None,
                 schedule: Sequence[tuple[float, Mode]] = (), ground: Array | None = None,
                 table: Array | None = None, trip: bool = True,
                 fast: bool | None = None, excite: Array | None = None,
                 plant: SystemConfig | None = None,
                 supervisor: Supervisor | None = None, allow_unstable: bool = False,
                 delay: Mapping[str, int] | None = None) -> None:
        self.cfg = cfg
        if supervisor is None and cfg.supervisor.enabled:
            supervisor = make_supervisor(cfg, mode, allow_unstable)
        self.supervisor = supervisor if trip else None
        if fast is None:
            fast = fastsim.available()
        self.fast = bool(fast and fastsim.available() and not any((delay or {}).values()))
        # the same numbers from either filter: the fast path's compiled one, or scipy's
        block = fastsim.sosfilt if self.fast else _scipy_sosfilt()
        self._feed = CheckpointFeed(cfg, block) if self.supervisor is not None else None
        n = cfg.plant.num_stages
        if plant is not None:
            check_plant(cfg, plant)
        self.sim = PlantSimulator(plant or cfg, seed=seed, ground=ground, table=table,
                                  block_filter=block)
        self.excite = _excite_array(cfg, excite)
        self._exc_offset = 0  # sample of the first row of self.excite
        self._exc_stop: int | None = None  # first sample without excitation (a trip)
        self.dec = Decoupler(cfg)
        active = enabled_controllers(mode, n)
        ids = controller_ids(n)
        self.ctrls = {cid: make_controller(cfg, cid, enabled=cid in active) for cid in ids}
        self.body = {cid: ControllerId.parse(cid).sensed_body for cid in ids}
        self.delay = DelayLines(delay or {}, set(ids), cfg.plant.dof)
        self.events = sorted(((int(round(t * cfg.plant.rate_hz)), m) for t, m in schedule),
                             key=lambda e: e[0])
        self._ei = 0
        self.modes: list[tuple[int, str]] = [(0, mode.label)]
        self.refused: list[tuple[int, str]] = []
        self.checker = (TripChecker(cfg.control, cfg.plant.rate_hz, n, cfg.plant.dof,
                                    block) if trip else None)
        self.trip: Trip | None = None
        self.k = 0
        self._loop = (fastsim.FastLoop(self.sim, self.dec, self.ctrls, self.body)
                      if self.fast else None)

    def _targets(self, on: frozenset[str]) -> None:
        for cid, c in self.ctrls.items():
            c.enable(cid in on)
        if self._loop is not None:
            self._loop.set_targets(on)

    def _apply_events(self) -> None:
        """Switches due at sample ``self.k``; refused while a trip is latched."""
        n = self.cfg.plant.num_stages
        while self._ei < len(self.events) and self.events[self._ei][0] <= self.k:
            m = self.events[self._ei][1]
            self._ei += 1
            if self.supervisor is not None:
                if self.supervisor.request(m, self.k - 1, (self.k - 1) * self.cfg.plant.dt):
                    self.refused.append((self.k, m.label))
                    continue
            elif self.trip is not None:
                if m is not Mode.PASSIVE:
                    self.refused.append((self.k, m.label))
                continue
            self._targets(enabled_controllers(m, n))
            self.modes.append((self.k, m.label))

    def _judge(self, velocity: Array, checker: TripChecker) -> tuple[int, Trip | None]:
        return checker.push(velocity[:, 1:])

    def _latch(self, trip: Trip) -> None:
        """Every controller off from the sample after the tripping checkpoint, and the
        excitation stopped there."""
        self.trip = trip
        self._targets(frozenset())
        self.modes.append((trip.sample + 1, Mode.PASSIVE.label))
        self._exc_stop = trip.sample + 1

    def _excite_rows(self, k0: int, m: int) -> Array | None:
        """Excitation of samples k0 .. k0+m-1, shape (m, N, dof) (zero past the given record
        and from a trip on); None when the run has none."""
        if self.excite is None:
            return None
        out = np.zeros((m, *self.excite.shape[1:]))
        end = self._exc_offset + self.excite.shape[0]
        stop = end if self._exc_stop is None else min(self._exc_stop, end)
        lo = max(k0, self._exc_offset)
        if lo < stop and lo < k0 + m:
            hi = min(k0 + m, stop)
            out[lo - k0:hi - k0] = self.excite[lo - self._exc_offset:hi - self._exc_offset]
        return out

    def feed_excitation(self, rows: Array) -> None:
        """Streaming: the excitation of the next block, samples ``k .. k + len(rows) - 1``
        (N, N*m; shape (m, N, dof)), in place of a whole run's record."""
        self.excite = _excite_array(self.cfg, rows)
        self._exc_offset = self.k

    def run(self, steps: int, progress: Callable[[float], None] | None = None
            ) -> SimResult | None:
        """The next ``steps`` samples (times continue from the previous block).

        Returns None when the fast path met a non-finite value (the objects are then spent:
        start again with ``fast=False``, which owns the fault handling).
        """
        n, dof = self.cfg.plant.num_stages, self.cfg.plant.dof
        out = (np.empty((steps, n + 1, dof)), np.empty((steps, len(self.sim.channels))),
               np.empty((steps, n + 1, dof)), np.empty((len(self.ctrls), steps, dof)),
               np.empty((steps, self.sim.num_actuators)))
        k0 = self.k
        modes0 = len(self.modes)
        sup0 = len(self.supervisor.transitions) if self.supervisor is not None else 0
        refused0 = len(self.refused)
        ok = (self._run_fast(steps, out, progress) if self._loop is not None
              else self._run_objects(steps, out, progress))
        if not ok:
            return None
        truth, raw, vel, wrench_all, applied = out
        wrench = {cid: wrench_all[i] for i, cid in enumerate(self.ctrls)}
        exc = self._excite_rows(k0, steps)
        counters = {"nonfinite_inputs": self.sim.nonfinite_inputs,
                    "saturations": self.sim.saturations}
        t = np.arange(k0, k0 + steps, dtype=np.float64) * self.cfg.plant.dt
        modes = self.modes[0 if k0 == 0 else modes0:]
        return SimResult(self.cfg, t, truth, raw, vel, wrench, applied, modes,
                         [c.name for c in self.sim.channels],
                         list(self.sim.actuator_names), counters, self.trip,
                         self.refused[refused0:], exc,
                         self.supervisor.transitions[sup0:] if self.supervisor is not None
                         else [])

    def _run_objects(self, steps: int, out: tuple[Array, ...],
                     progress: Callable[[float], None] | None) -> bool:
        truth, raw, vel, wrench_all, applied = out
        sim, dec = self.sim, self.dec
        every = max(steps // 100, 1)
        check = self.checker.every if self.checker is not None else 0
        pushed = 0  # rows of this block already given to the trip checker
        for k in range(steps):
            self._apply_events()
            truth[k] = sim.truth()
            r = sim.measure()
            raw[k] = r
            tw = dec.step(r)
            vel[k] = tw
            w_out = {}
            for i, (cid, c) in enumerate(self.ctrls.items()):
                w = c.step(tw[self.body[cid]])
                wrench_all[i, k] = w
                w_out[cid] = self.delay.shift(cid, w)
            exc = self._excite_rows(self.k, 1)
            applied[k] = sim.advance(w_out, None if exc is None else exc[0])
            self.k += 1
            if (self.checker is not None and self.trip is None and self.k % check == 0):
                _, trip = self._judge(vel[pushed:k + 1], self.checker)
                if self._feed is not None:
                    self._supervise(vel[pushed:k + 1, 0], applied[pushed:k + 1])
                elif trip is not None:
                    self._latch(trip)
                pushed = k + 1
            if progress is not None and k % every == 0:
                progress(k / steps)
        if self.checker is not None and self.trip is None and pushed < steps:
            self._judge(vel[pushed:steps], self.checker)  # a partial checkpoint block
            if self._feed is not None:
                self._feed.feed(vel[pushed:steps, 0], applied[pushed:steps])
        return True

    def _supervise(self, ground: Array, applied: Array) -> None:
        """Step the supervisor at the checkpoint ending at sample ``self.k - 1``; the mode it
        chooses runs from ``self.k``."""
        assert self._feed is not None and self.supervisor is not None
        assert self.checker is not None
        self._feed.feed(ground, applied)
        before = self.supervisor.mode
        tr = self.supervisor.step(self._feed.checkpoint(self.k - 1, self.checker))
        if tr is not None and tr.state in (State.TRIPPED, State.LATCHED) \
                and self._exc_stop is None:
            self._exc_stop = self.k  # an identification run ends at its first trip
        mode = self.supervisor.mode
        if mode is not before:
            self._targets(enabled_controllers(mode, self.cfg.plant.num_stages))
            self.modes.append((self.k, mode.label))

    def _run_fast(self, steps: int, out: tuple[Array, ...],
                  progress: Callable[[float], None] | None) -> bool:
        loop = self._loop
        assert loop is not None
        every = max(steps // 100, 1)
        ticks = set(range(1, steps + 1, every)) if progress is not None else set()
        k0 = self.k
        # supervised: every segment ends at or before a checkpoint, where the supervisor's
        # decision applies from the next sample as on the object path
        check = self.checker.every if self._feed is not None and self.checker else steps + 1
        bounds = sorted({0, steps, *range(0, steps, fastsim.BLOCK), *ticks,
                         *(e - k0 for e, _ in self.events if 0 < e - k0 < steps),
                         *range(-k0 % check, steps, check)})
        for b0, b1 in itertools.pairwise(bounds):
            self._apply_events()
            inputs = loop.draw(b1 - b0, self._excite_rows(self.k, b1 - b0))
            rows = _rows(out, b0, b1)
            if not self._segment(loop, inputs, rows):
                return False
            if self._feed is not None and self.checker is not None:
                self._judge(rows[2], self.checker)
                if self.k % check == 0:
                    self._supervise(rows[2][:, 0], rows[4])
                else:
                    self._feed.feed(rows[2][:, 0], rows[4])
            if progress is not None and (b1 - 1) % every == 0:
                progress((b1 - 1) / steps)
        loop.sync(self.k)
        return True

    def _segment(self, loop: fastsim.FastLoop, inputs: fastsim.Inputs,
                 out: tuple[Array, ...]) -> bool:
        """Rows of one block; a trip inside it is found on a copy of the checker, then the
        block is run again up to the tripping checkpoint, so it lands where the object path
        puts it."""
        m = inputs.ground.shape[0]
        judge = self.checker is not None and self.trip is None and self._feed is None
        snap = loop.snapshot() if judge else None
        if loop.run(inputs, out) != m:
            return False
        if not judge:
            self.k += m
            return True
        assert self.checker is not None and snap is not None
        trial = self.checker.clone()
        used, trip = self._judge(out[2], trial)
        self.checker = trial
        if trip is None:
            self.k += m
            return True
        loop.restore(snap)
        if loop.run(inputs.rows(0, used), _rows(out, 0, used)) != used:
            return False
        self.k += used
        self._latch(trip)
        inputs.excite[used:] = 0.0  # no excitation while tripped
        rest = m - used
        if rest and loop.run(inputs.rows(used, m), _rows(out, used, m)) != rest:
            return False
        self.k += rest
        return True


def _excite_array(cfg: SystemConfig, excite: Array | None) -> Array | None:
    """``excite`` as a finite float array (K, N, dof), or None."""
    if excite is None:
        return None
    e = np.asarray(excite, dtype=np.float64)
    shape = (cfg.plant.num_stages, cfg.plant.dof)
    if e.ndim != 3 or e.shape[1:] != shape:
        raise ConfigError(f"excitation: expected shape (K, {shape[0]}, {shape[1]}), got "
                          f"{e.shape}")
    if not np.isfinite(e).all():
        raise ConfigError("excitation: contains NaN or Inf")
    return e


def _rows(out: tuple[Array, ...], i0: int, i1: int) -> tuple[Array, ...]:
    """Rows i0..i1-1 of the output arrays (the wrench array is (nc, K, dof))."""
    truth, raw, vel, wrench, applied = out
    return (truth[i0:i1], raw[i0:i1], vel[i0:i1], wrench[:, i0:i1], applied[i0:i1])


def _scipy_sosfilt() -> BlockFilter:
    """scipy's block filter for the object path, imported only then: ``scipy.signal`` took
    0.65 s of every ``dcsms sim`` start-up whose fast path never used it (docs/performance.md)."""
    from dcsms_ros.core import compiledsos  # noqa: PLC0415 - scipy.signal: the object path only

    return compiledsos.sosfilt
