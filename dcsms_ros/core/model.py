"""Continuous N-stage cascade plant (1-DOF vertical or 6-DOF rigid body) and its exact ZOH form.

Every body's generalised coordinates ``q_i`` (6dof: translation and small rotation) are taken at
the world origin, so the deflection of a mount at world point ``p`` between stage ``i-1`` and
stage ``i`` is ``T(p) (q_i - q_{i-1})`` with ``T(p) = [I, -skew(p)]``, and the generalised force
of a wrench is simply that wrench taken about the origin. The states are the relative
displacements ``e_i = q_i - q_{i-1}`` then the absolute velocities ``qdot_i``: with positive
definite suspensions this makes ``A`` asymptotically stable (no free integrator of the ground
position). Principal axes of inertia are assumed parallel to the world axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.geometry import (
    check_stiffness,
    drive_matrix,
    mount_matrices,
    skew,
    twist_transform,
)
from dcsms_ros.core.schema import AXES6
from dcsms_ros.errors import ConfigError, GeometryError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class StateSpace:
    """``xdot = a x + b u`` (or ``x[k+1] = a x[k] + b u[k]``), ``y = c x + d u``.

    ``dt`` is 0 for a continuous system, the sample period (s) for a discrete one.
    """

    a: Array
    b: Array
    c: Array
    d: Array
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    dt: float = 0.0

    @property
    def nstates(self) -> int:
        return int(self.a.shape[0])


def axis_names(dof: int) -> tuple[str, ...]:
    """Axis labels of a per-body vector: ``("z",)`` for 1dof, ``AXES6`` for 6dof."""
    return ("z",) if dof == 1 else AXES6


def actuator_count(cfg: SystemConfig, stage_index: int) -> int:
    """Number of actuator input channels of stage ``stage_index`` (1-based): 1 in 1dof (the
    voice coils are lumped), the number of actuators in 6dof."""
    st = cfg.plant.stages[stage_index - 1]
    return 1 if cfg.plant.dof == 1 else len(st.actuators.position)


def suspension_matrices(cfg: SystemConfig, i: int) -> tuple[Array, Array]:
    """Stiffness and damping of the suspension under stage ``i`` (1-based), shape (dof, dof),
    in origin coordinates (N/m, N*s/m; 6dof also N*m/rad etc.).

    Raises
    ------
    ConfigError
        If a 6dof mount layout leaves a rigid-body axis unsupported (singular stiffness).
    """
    st = cfg.plant.stages[i - 1]
    if cfg.plant.dof == 1:
        return np.array([[st.stiffness]]), np.array([[st.damping]])
    k, c = mount_matrices(np.asarray(st.mounts.position, float),
                          np.asarray(st.mounts.stiffness, float),
                          np.asarray(st.mounts.damping, float))
    try:
        check_stiffness(k, f"{st.name}.mounts")
    except GeometryError as exc:
        raise ConfigError(f"{cfg.source}: {exc}") from None
    return k, c


def mass_matrix(cfg: SystemConfig, i: int) -> Array:
    """Mass matrix of stage ``i`` (1-based) in origin coordinates, shape (dof, dof).

    For a CoM at ``c``: ``[[m I, -m [c]x], [m [c]x, I_c - m [c]x^2]]`` (kg, kg*m, kg*m^2).
    """
    st = cfg.plant.stages[i - 1]
    if cfg.plant.dof == 1:
        return np.array([[st.mass]])
    sc = skew(np.asarray(st.com, float))
    m = st.mass
    out = np.zeros((6, 6))
    out[:3, :3] = m * np.eye(3)
    out[:3, 3:] = -m * sc
    out[3:, :3] = m * sc
    out[3:, 3:] = np.diag(st.inertia) - m * sc @ sc
    return out


def reference_transform(cfg: SystemConfig, i: int) -> Array:
    """(dof, dof) map from origin-coordinate velocities of stage ``i`` to its twist at its
    reference point (the CoM); identity in 1dof."""
    if cfg.plant.dof == 1:
        return np.eye(1)
    return twist_transform(np.zeros(3), np.asarray(cfg.plant.stages[i - 1].com, float))


def actuator_wrench_matrix(cfg: SystemConfig, i: int) -> Array:
    """Drive matrix of stage ``i`` about its reference point, shape (dof, n_act_i): the wrench
    the actuator forces apply to stage ``i`` (the opposite wrench acts on stage ``i-1``)."""
    st = cfg.plant.stages[i - 1]
    if cfg.plant.dof == 1:
        return np.ones((1, 1))
    return drive_matrix(np.asarray(st.actuators.position, float),
                        np.asarray(st.actuators.direction, float), np.asarray(st.com, float))


def _blockdiag(blocks: list[Array]) -> Array:
    return np.asarray(scipy.linalg.block_diag(*blocks), dtype=float)


def plant_state_space(cfg: SystemConfig) -> StateSpace:
    """Continuous state-space model of the cascade.

    Parameters
    ----------
    cfg : SystemConfig
        1dof or 6dof, N >= 1 stages.

    Returns
    -------
    StateSpace
        States (2*N*dof): relative displacements ``e_i`` (m, rad) then absolute velocities at the
        origin (m/s, rad/s). Inputs: ground twist at the origin (dof; m/s, rad/s) | actuator forces
        stage by stage (N; 1 lumped channel per stage in 1dof) | disturbance wrench on each stage
        about its reference point (N*dof; N, N*m). Outputs: absolute twist of each stage at its
        reference point (N*dof). ``d`` is zero.
    """
    n, dof = cfg.plant.num_stages, cfg.plant.dof
    nd = n * dof
    ks, cs = zip(*(suspension_matrices(cfg, i) for i in range(1, n + 1)), strict=True)
    kd, cd = _blockdiag(list(ks)), _blockdiag(list(cs))
    minv = np.linalg.inv(_blockdiag([mass_matrix(cfg, i) for i in range(1, n + 1)]))
    # e = D q - E0 q0: the spring of stage i pushes +stage i and -stage i-1, hence D^T below
    dmat = np.eye(nd) - np.eye(nd, k=-dof)
    e0 = np.zeros((nd, dof))
    e0[:dof, :] = np.eye(dof)
    xs = [reference_transform(cfg, i) for i in range(1, n + 1)]
    # a wrench about the reference point enters origin coordinates as X^T w (power balance)
    gact = _blockdiag([xs[i - 1].T @ actuator_wrench_matrix(cfg, i) for i in range(1, n + 1)])
    a = np.zeros((2 * nd, 2 * nd))
    a[:nd, nd:] = dmat
    a[nd:, :nd] = -minv @ dmat.T @ kd
    a[nd:, nd:] = -minv @ dmat.T @ cd @ dmat
    b_ground = np.vstack([-e0, minv @ dmat.T @ cd @ e0])
    b_act = np.vstack([np.zeros((nd, gact.shape[1])), minv @ dmat.T @ gact])
    b_dist = np.vstack([np.zeros((nd, nd)), minv @ _blockdiag([x.T for x in xs])])
    c = np.hstack([np.zeros((nd, nd)), _blockdiag(xs)])
    b = np.hstack([b_ground, b_act, b_dist])
    ax = axis_names(dof)
    inputs = [f"ground.v{a_}" for a_ in ax]
    inputs += [f"{st.name}.act{j}" for i, st in enumerate(cfg.plant.stages, 1)
               for j in range(actuator_count(cfg, i))]
    inputs += [f"{st.name}.w{a_}" for st in cfg.plant.stages for a_ in ax]
    outputs = [f"{st.name}.v{a_}" for st in cfg.plant.stages for a_ in ax]
    return StateSpace(a, b, c, np.zeros((nd, b.shape[1])), tuple(inputs), tuple(outputs))


def input_slices(cfg: SystemConfig) -> tuple[slice, slice, slice]:
    """Column slices of :func:`plant_state_space`'s ``b``: ground, actuators, disturbances."""
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    n_act = sum(actuator_count(cfg, i) for i in range(1, n + 1))
    return slice(0, dof), slice(dof, dof + n_act), slice(dof + n_act, dof + n_act + n * dof)


def wrench_input_matrix(cfg: SystemConfig, ss: StateSpace | None = None) -> Array:
    """Input matrix for a commanded wrench per stage (N*dof columns, stage by stage), allocated
    to that stage's actuators with ``pinv(drive matrix)`` as the allocator does, reactions
    included; shape (nstates, N*dof)."""
    ss = plant_state_space(cfg) if ss is None else ss
    _, act, _ = input_slices(cfg)
    alloc = _blockdiag([np.asarray(np.linalg.pinv(actuator_wrench_matrix(cfg, i)), dtype=float)
                        for i in range(1, cfg.plant.num_stages + 1)])
    return np.asarray(ss.b[:, act] @ alloc, dtype=float)


def discretize(ss: StateSpace, dt: float) -> StateSpace:
    """Exact zero-order-hold discretisation with sample period ``dt`` (s).

    ``expm([[A, B], [0, 0]] dt) = [[Ad, Bd], [0, I]]``; ``c`` and ``d`` are unchanged.
    """
    if not dt > 0.0:
        raise ValueError(f"discretize: dt must be > 0, got {dt!r}")
    nx, nu = ss.b.shape
    aug = np.zeros((nx + nu, nx + nu))
    aug[:nx, :nx] = ss.a
    aug[:nx, nx:] = ss.b
    ex = scipy.linalg.expm(aug * dt)
    return StateSpace(ex[:nx, :nx].copy(), ex[:nx, nx:].copy(), ss.c.copy(), ss.d.copy(),
                      ss.input_names, ss.output_names, float(dt))


class DiscretePlant:
    """Stepping a discrete plant: ``y_k = C x_k``, ``x_{k+1} = Ad x_k + Bd u_k``.

    Parameters
    ----------
    ss : StateSpace
        Discrete model from :func:`discretize` (``d`` is ignored: it is zero for the plant).
    """

    def __init__(self, ss: StateSpace) -> None:
        self.ss = ss
        self._a = np.ascontiguousarray(ss.a, dtype=np.float64)
        self._b = np.ascontiguousarray(ss.b, dtype=np.float64)
        self._c = np.ascontiguousarray(ss.c, dtype=np.float64)
        self.x = np.zeros(ss.a.shape[0])
        self._ax = np.zeros_like(self.x)
        self._bu = np.zeros_like(self.x)
        self.n_inputs = int(ss.b.shape[1])
        self.n_outputs = int(ss.c.shape[0])

    @property
    def a(self) -> Array:
        """``Ad`` (nx, nx), the array :meth:`step` multiplies with (shared; do not write)."""
        return self._a

    @property
    def b(self) -> Array:
        """``Bd`` (nx, n_inputs), the array :meth:`step` multiplies with (shared)."""
        return self._b

    @property
    def c(self) -> Array:
        """``C`` (n_outputs, nx), the array :meth:`output` multiplies with (shared)."""
        return self._c

    def step(self, u: Array) -> None:
        """Advance one sample with input ``u`` (n_inputs,) held over the period."""
        np.dot(self._a, self.x, out=self._ax)
        np.dot(self._b, np.asarray(u, dtype=np.float64), out=self._bu)
        np.add(self._ax, self._bu, out=self.x)

    def output(self) -> Array:
        """Stage twists at their reference points for the current state, shape (N*dof,)."""
        return np.dot(self._c, self.x)

    def reset(self) -> None:
        """Zero the state (every stage at rest on its suspension)."""
        self.x[:] = 0.0
