"""Batch closed-loop simulation without ROS.

It steps exactly the objects the nodes step — :class:`PlantSimulator` (plant node),
:class:`Decoupler` (sensor-decoupling node), the feedback and feedforward loops (controller nodes)
— in the order the lockstep graph does, so a lockstep graph with the same configuration and seed
reproduces :func:`simulate` sample for sample.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core import fastsim
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import make_controller
from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.core.modes import Mode, controller_ids, controller_stage, enabled_controllers
from dcsms_ros.core.simulator import PlantSimulator

Array = NDArray[np.float64]


@dataclass
class SimResult:
    """Time series of one batch run; K samples at ``cfg.plant.rate_hz``.

    Attributes
    ----------
    t : ndarray, shape (K,)
        Sample times, s.
    truth : ndarray, shape (K, N+1, dof)
        True twists of ground and stages (m/s, rad/s).
    raw : ndarray, shape (K, n_channels)
        Geophone readings, m/s.
    velocity : ndarray, shape (K, N+1, dof)
        Decoupled twists of ground and stages (what the controllers see).
    wrench : dict of controller id to ndarray, shape (K, dof)
        Each controller's command (N, N*m).
    applied : ndarray, shape (K, n_actuators)
        Forces actually applied by the actuators, N.
    mode : list of (sample index, label)
        Mode changes: the first entry is the starting mode.
    """

    cfg: SystemConfig
    t: Array
    truth: Array
    raw: Array
    velocity: Array
    wrench: dict[str, Array]
    applied: Array
    mode: list[tuple[int, str]]
    channel_names: list[str] = field(default_factory=list)
    actuator_names: list[str] = field(default_factory=list)
    counters: dict[str, int] = field(default_factory=dict)


def simulate(cfg: SystemConfig, mode: Mode, duration_s: float, seed: int | None = None,
             schedule: Sequence[tuple[float, Mode]] = (), ground: Array | None = None,
             progress: Callable[[float], None] | None = None,
             fast: bool | None = None) -> SimResult:
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
    """
    if fast is None:
        fast = fastsim.available()
    if fast and fastsim.available():
        res = _simulate(cfg, mode, duration_s, seed, schedule, ground, progress, True)
        if res is not None:
            return res
    res = _simulate(cfg, mode, duration_s, seed, schedule, ground, progress, False)
    assert res is not None
    return res


def _simulate(cfg: SystemConfig, mode: Mode, duration_s: float, seed: int | None,
              schedule: Sequence[tuple[float, Mode]], ground: Array | None,
              progress: Callable[[float], None] | None, fast: bool) -> SimResult | None:
    n = cfg.plant.num_stages
    steps = int(round(duration_s * cfg.plant.rate_hz))
    sim = PlantSimulator(cfg, seed=seed, ground=ground)
    dec = Decoupler(cfg)
    active = enabled_controllers(mode, n)
    ids = controller_ids(n)
    ctrls = {cid: make_controller(cfg, cid, enabled=cid in active) for cid in ids}
    body = {cid: (0 if cid.startswith("ff") else controller_stage(cid)) for cid in ids}
    dof = cfg.plant.dof
    truth = np.empty((steps, n + 1, dof))
    vel = np.empty((steps, n + 1, dof))
    raw = np.empty((steps, len(sim.channels)))
    wrench_all = np.empty((len(ids), steps, dof))
    wrench = {cid: wrench_all[i] for i, cid in enumerate(ids)}
    applied = np.empty((steps, sim.num_actuators))
    events = sorted(((int(round(t * cfg.plant.rate_hz)), m) for t, m in schedule),
                    key=lambda e: e[0])
    modes = [(0, mode.label)]
    if fast:
        loop = fastsim.FastLoop(sim, dec, ctrls, body, (truth, raw, vel, wrench_all, applied))
        if not fastsim.run_fast(loop, steps, events, n, modes, progress):
            return None
        return _result(cfg, sim, steps, truth, raw, vel, wrench, applied, modes)
    every = max(steps // 100, 1)
    ei = 0
    for k in range(steps):
        while ei < len(events) and events[ei][0] <= k:
            on = enabled_controllers(events[ei][1], n)
            for cid, c in ctrls.items():
                c.enable(cid in on)
            modes.append((k, events[ei][1].label))
            ei += 1
        truth[k] = sim.truth()
        r = sim.measure()
        raw[k] = r
        tw = dec.step(r)
        vel[k] = tw
        out = {}
        for cid, c in ctrls.items():
            w = c.step(tw[body[cid]])
            wrench[cid][k] = w
            out[cid] = w
        applied[k] = sim.advance(out)
        if progress is not None and k % every == 0:
            progress(k / steps)
    return _result(cfg, sim, steps, truth, raw, vel, wrench, applied, modes)


def _result(cfg: SystemConfig, sim: PlantSimulator, steps: int, truth: Array, raw: Array,
            vel: Array, wrench: dict[str, Array], applied: Array,
            modes: list[tuple[int, str]]) -> SimResult:
    counters = {"nonfinite_inputs": sim.nonfinite_inputs, "saturations": sim.saturations}
    t = np.arange(steps, dtype=np.float64) * cfg.plant.dt
    return SimResult(cfg, t, truth, raw, vel, wrench, applied, modes,
                     [c.name for c in sim.channels], list(sim.actuator_names), counters)
