"""The physical side of the loop: plant, geophones, disturbances and the actuators.

The ROS plant-simulator node and the batch engine both drive one :class:`PlantSimulator`, so a
lockstep graph and a batch run compute the same floating-point operations in the same order.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import Allocator
from dcsms_ros.core.disturbance import Disturbances
from dcsms_ros.core.model import DiscretePlant, discretize, plant_state_space
from dcsms_ros.core.modes import ControllerId
from dcsms_ros.core.sensors import GeophoneArray, channel_layout, channel_matrix
from dcsms_ros.core.sosfilter import BlockFilter, sosfilt
from dcsms_ros.errors import ConfigError

Array = NDArray[np.float64]

#: Stream id of the geophone self-noise, kept apart from the disturbance streams of the seed.
_SENSOR_STREAM = 7


#: Parameters a simulated plant may hold apart from the configuration the controllers run with
#: (``dcsms sim --plant-set``): the physics, the geophone dynamics and the disturbances, never the
#: structure (stages, fidelity, rate, transducer layout) or the controllers.
PLANT_STAGE_KEYS = ("mass", "stiffness", "damping", "inertia", "mounts.position",
                    "mounts.stiffness", "mounts.damping")
PLANT_KEYS = ("sensors.natural_frequency_hz", "sensors.damping_ratio", "sensors.noise_asd")


def plant_parameter(name: str) -> bool:
    """True for a dotted name that :func:`check_plant` lets a plant hold apart."""
    head, _, rest = name.partition(".")
    if head.startswith("stage") and head[5:].isdigit():
        return rest in PLANT_STAGE_KEYS
    return name in PLANT_KEYS or head == "disturbance"


def check_plant(cfg: SystemConfig, plant: SystemConfig) -> None:
    """Check that ``plant`` differs from ``cfg`` only in :func:`plant_parameter` names.

    Raises
    ------
    ConfigError
        Naming the first parameter that may not differ.
    """
    a, b = dict(cfg.params or {}), dict(plant.params or {})
    for name in sorted(set(a) | set(b)):
        if a.get(name) != b.get(name) and not plant_parameter(name):
            raise ConfigError(f"plant: '{name}' must equal the configuration's (only masses, "
                              "inertias, suspensions, geophone dynamics and disturbances may "
                              "differ)")


def finite(v: ArrayLike) -> bool:
    """Whether every element of ``v`` is finite; for the few floats of a wrench per sample a
    Python loop (~0.3 us) instead of ``np.all(np.isfinite(v))`` (~2.7 us)."""
    return all(map(math.isfinite, np.asarray(v).ravel().tolist()))


class PlantSimulator:
    """Sample-by-sample simulation of the cascade with its sensors and actuators.

    Per sample k: :meth:`measure` (geophone readings of state x_k, idempotent within a sample),
    then :meth:`advance` with every controller's wrench, which allocates and saturates the actuator
    forces, holds them (ZOH) with the ground velocity and table forces of sample k, and steps to
    k+1.

    Parameters
    ----------
    cfg : SystemConfig
        The system.
    seed : int, optional
        Seed of every random stream (ground, table forces, sensor noise); default
        ``cfg.disturbance.seed``.
    ground : ndarray, shape (K, dof), optional
        Recorded ground velocity (m/s) at the control rate, replayed instead of white noise.
    table : ndarray, shape (K, N, dof), optional
        Wrenches added to the table forces of the first K samples (N, N*m).
    disturbances : bool
        False: no ground motion and no table forces at all (and none drawn: a loop model
        only needs the plant's matrices, cheaply).
    block_filter : callable
        Runs the disturbances' band-passes (:data:`.sosfilter.BlockFilter`).
    """

    def __init__(self, cfg: SystemConfig, seed: int | None = None,
                 ground: Array | None = None, table: Array | None = None,
                 disturbances: bool = True, block_filter: BlockFilter = sosfilt) -> None:
        self.cfg = cfg
        seed = cfg.disturbance.seed if seed is None else seed
        self.plant = DiscretePlant(discretize(plant_state_space(cfg), cfg.plant.dt))
        self.disturbances = (Disturbances(cfg, seed=seed, ground=ground, table=table,
                                          block_filter=block_filter)
                             if disturbances else None)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_SENSOR_STREAM,)))
        self.geophones = GeophoneArray(cfg, rng)
        self.channels = channel_layout(cfg)
        self._chan = channel_matrix(cfg)
        self.allocators = [Allocator(cfg, i) for i in range(1, cfg.plant.num_stages + 1)]
        self.actuator_names = [f"{s.name}/a{j}" for s, a in
                               zip(cfg.plant.stages, self.allocators, strict=True)
                               for j in range(a.n_act)]
        self.dof = cfg.plant.dof
        self.k = 0
        self.nonfinite_inputs = 0
        self.saturations = 0
        self._n_act = sum(a.n_act for a in self.allocators)
        n_in = self.dof + self._n_act + cfg.plant.num_stages * self.dof
        self._u = np.zeros(n_in)
        self._truth = np.zeros((cfg.plant.num_stages + 1, self.dof))
        self._raw: Array | None = None
        self._rows: dict[str, int] = {}  # controller id -> its stage's row of the totals
        self._draw()

    @property
    def t(self) -> float:
        """Time of the current sample k, in s."""
        return self.k * self.cfg.plant.dt

    @property
    def num_actuators(self) -> int:
        return self._n_act

    @property
    def channel_matrix(self) -> Array:
        """(n_ch, (N+1)*dof) map from true twists [ground, stages] to channel velocities."""
        return self._chan

    @property
    def sample_inputs(self) -> tuple[Array, Array]:
        """Ground twist (dof,) m/s, rad/s and table wrenches (N, dof) N, N*m of sample k, as
        drawn (the arrays :meth:`advance` holds over the period; do not write)."""
        return self._ground, self._dist

    def _draw(self) -> None:
        if self.disturbances is None:
            self._ground = np.zeros(self.cfg.plant.dof)
            self._dist = np.zeros((self.cfg.plant.num_stages, self.cfg.plant.dof))
        else:
            self._ground, self._dist = self.disturbances.next()
        self._raw = None

    def truth(self) -> Array:
        """True twists of ground and stages at sample k, shape (N+1, dof), m/s and rad/s."""
        self._truth[0] = self._ground
        self._truth[1:] = self.plant.output().reshape(-1, self.dof)
        return self._truth

    def measure(self) -> Array:
        """Geophone readings at sample k, shape (n_channels,), m/s. Repeated calls within one
        sample return the same readings (a retransmitted lockstep step must not re-step the
        geophone filters)."""
        if self._raw is None:
            true_ch = self._chan @ self.truth().ravel()
            self._raw = self.geophones.step(true_ch)
        return self._raw

    def _row_of(self, cid: str) -> int:
        row = self._rows.get(cid)
        if row is None:
            row = self._rows[cid] = ControllerId.parse(cid).stage - 1
        return row

    def advance(self, wrenches: Mapping[str, Array], excitation: Array | None = None) -> Array:
        """Apply the controllers' wrenches for sample k and step to k+1.

        Parameters
        ----------
        wrenches : mapping of controller id to ndarray, shape (dof,)
            Wanted wrench (N, N*m) of each controller at its stage's reference point; missing
            controllers contribute nothing. A non-finite wrench is never applied: it counts as
            zero and increments :attr:`nonfinite_inputs`.
        excitation : ndarray, shape (N, dof), optional
            Excitation wrench per stage (:mod:`.excitation`), added after the controllers'
            and allocated and clipped with them; non-finite counts as above.

        Returns
        -------
        ndarray, shape (n_actuators,)
            Force actually applied by each actuator, N (after saturation).
        """
        if self._raw is None:
            self.measure()  # the geophones sample every step even if nobody asked
        # Python floats, added in the same order as the batch engine's loop (the same bits):
        # a numpy row update per controller cost ~1.5 us on the composed graph's step
        rows = [[0.0] * self.dof for _ in self.allocators]
        for cid, w in wrenches.items():
            v = np.asarray(w).ravel().tolist()
            if not all(map(math.isfinite, v)):
                self.nonfinite_inputs += 1
                continue
            if len(v) != self.dof:
                raise ValueError(f"{cid}: wrench of {len(v)} components, the plant has "
                                 f"{self.dof} degrees of freedom")
            row = rows[self._row_of(cid)]
            for j, x in enumerate(v):
                row[j] += x
        totals = np.array(rows)
        if excitation is not None:
            if finite(excitation):
                totals += excitation
            else:
                self.nonfinite_inputs += 1
        u = self._u
        u[: self.dof] = self._ground
        pos = self.dof
        for i, alloc in enumerate(self.allocators):
            forces, n_sat = alloc.clip(alloc.forces(totals[i]))
            self.saturations += n_sat
            u[pos: pos + alloc.n_act] = forces
            pos += alloc.n_act
        applied = u[self.dof: pos].copy()
        u[pos:] = self._dist.ravel()
        self.plant.step(u)
        self.k += 1
        self._draw()
        return applied
