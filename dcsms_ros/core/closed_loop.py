"""The plant of :mod:`.model` closed by the controllers of a mode, as one state-space system.

Each enabled controller is a set of SISO links (one per axis): a measured velocity (a stage
twist component, or the ground's for feedforward) through its :mod:`.filters` transfer function
to the commanded wrench component of a stage, applied through that stage's actuators with
``pinv(drive matrix)`` (reaction on the stage below), exactly as the allocator does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import control as ct
import numpy as np
import scipy.linalg

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import suspension_totals  # same FF axis totals as the loop
from dcsms_ros.core.filters import feedback_tf, feedforward_tf
from dcsms_ros.core.lti import Array, as_tf, ss_to_tf
from dcsms_ros.core.model import input_slices, plant_state_space, wrench_input_matrix
from dcsms_ros.core.modes import (
    FEEDBACK,
    FEEDFORWARD,
    FF_STAGE1,
    ControllerId,
    Mode,
    enabled_controllers,
)
from dcsms_ros.core.schema import AXES6
from dcsms_ros.core.sensors import extension_tf, geophone_tf
from dcsms_ros.errors import ConfigError

AXIS_INDEX = {name: i for i, name in enumerate(AXES6)}
_Z = AXIS_INDEX["z"]


def axis_index(axis: str | int, dof: int) -> int:
    """Index into a per-body vector of length ``dof`` for ``axis`` (``x``..``rz`` or 0..5)."""
    a = AXIS_INDEX[axis] if isinstance(axis, str) and axis in AXIS_INDEX else axis
    if not isinstance(a, int) or not 0 <= a < 6:
        raise ConfigError(f"unknown axis {axis!r}; expected one of {', '.join(AXES6)}")
    if dof == 1:
        if a != _Z:
            raise ConfigError(f"axis {axis!r}: the 1dof model has only z")
        return 0
    return a


@dataclass(frozen=True)
class Link:
    """One SISO controller path: ``wrench[dst] = -tf * (stage twists[src] | ground[src])``.

    ``dst``/``src`` index the stacked per-stage vectors (stage i, axis a -> (i-1)*dof + a);
    ``kind`` is ``fb`` (source: stage velocity) or ``ff`` (source: ground velocity).
    """

    controller: str
    kind: str
    tf: Any
    src: int
    dst: int


def controller_links(cfg: SystemConfig, mode: Mode, sensors: bool = False) -> list[Link]:
    """Every non-zero SISO path of the controllers ``mode`` enables (N-stage aware)."""
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    axes = [(0, _Z)] if dof == 1 else [(a, a) for a in range(6)]
    sensor = _sensor_tf(cfg) if sensors else None
    links = []
    enabled = enabled_controllers(mode, n)
    for i in range(1, n + 1):
        name = str(ControllerId(FEEDBACK, i))
        if name not in enabled:
            continue
        for a, a6 in axes:
            tf = feedback_tf(cfg.feedback[i - 1], a6)
            if not tf.is_zero():
                links.append(Link(name, FEEDBACK, as_tf(tf), (i - 1) * dof + a,
                                  (i - 1) * dof + a))
    if FF_STAGE1 in enabled and cfg.feedforward.gain != 0.0:
        totals = suspension_totals(cfg, 1)
        for a, a6 in axes:
            if a6 < 3 and (totals[a6][0] or totals[a6][1]):
                links.append(Link(FF_STAGE1, FEEDFORWARD, as_tf(feedforward_tf(
                    cfg.feedforward, *totals[a6])), a, a))
    if sensor is not None:
        links = [Link(k.controller, k.kind, k.tf * sensor, k.src, k.dst) for k in links]
    return links


def _sensor_tf(cfg: SystemConfig) -> Any:
    return as_tf(geophone_tf(cfg.sensors) * extension_tf(cfg.sensors))


def _controller_ss(links: list[Link]) -> tuple[Array, Array, Array, Array]:
    blocks = [ct.tf2ss(k.tf) for k in links]
    ac = scipy.linalg.block_diag(*[np.asarray(b.A, float) for b in blocks])
    bc = scipy.linalg.block_diag(*[np.asarray(b.B, float).reshape(-1, 1) for b in blocks])
    cc = scipy.linalg.block_diag(*[np.asarray(b.C, float).reshape(1, -1) for b in blocks])
    dc = np.diag([float(np.asarray(b.D).reshape(-1)[0]) for b in blocks])
    nc = ac.shape[0] if ac.size else 0
    return (ac.reshape(nc, nc), bc.reshape(nc, len(links)), cc.reshape(len(links), nc),
            dc.reshape(len(links), len(links)))


def closed_loop_ss(cfg: SystemConfig, mode: Mode, sensors: bool = False,
                   exclude: Link | None = None) -> Any:
    """Closed-loop state space of the cascade under ``mode``.

    Parameters
    ----------
    cfg : SystemConfig
    mode : Mode
    sensors : bool
        Include geophone and extension dynamics in every measured velocity.
    exclude : Link, optional
        Leave this path open (for loop gains).

    Returns
    -------
    control.StateSpace
        Inputs: ground twist (dof) then a commanded wrench per stage through its actuators
        (N*dof); outputs: stage twists at their reference points (N*dof). States: plant, then
        controller states.
    """
    ss = plant_state_space(cfg)
    g, _, _ = input_slices(cfg)
    dof, nd = cfg.plant.dof, cfg.plant.num_stages * cfg.plant.dof
    bg, bw, c = ss.b[:, g], wrench_input_matrix(cfg, ss), ss.c
    links = [k for k in controller_links(cfg, mode, sensors)
             if exclude is None or (k.controller, k.dst) != (exclude.controller, exclude.dst)]
    nx = ss.a.shape[0]
    if not links:
        return ct.ss(ss.a, np.hstack([bg, bw]), c, np.zeros((nd, dof + nd)))
    ac, bc, cc, dc = _controller_ss(links)
    nl = len(links)
    lzx = np.zeros((nl, nx))  # controller inputs z = lzx x + lzg v_ground
    lzg = np.zeros((nl, dof))
    wout = np.zeros((nd, nl))  # wrench = -wout * controller outputs
    for j, k in enumerate(links):
        if k.kind == FEEDBACK:
            lzx[j] = c[k.src]
        else:
            lzg[j, k.src] = 1.0
        wout[k.dst, j] = 1.0
    bwo = bw @ wout
    nc = ac.shape[0]
    a = np.block([[ss.a - bwo @ dc @ lzx, -bwo @ cc], [bc @ lzx, ac]])
    b = np.block([[bg - bwo @ dc @ lzg, bw], [bc @ lzg, np.zeros((nc, nd))]])
    cl = np.hstack([c, np.zeros((nd, nc))])
    return ct.ss(a, b, cl, np.zeros((nd, dof + nd)))


def siso(sys: Any, inp: int, out: int) -> Any:
    """Transfer function from input ``inp`` to output ``out`` of a state-space system."""
    a = np.asarray(sys.A, dtype=float)
    return ss_to_tf(a, np.asarray(sys.B, float)[:, inp], np.asarray(sys.C, float)[out],
                    float(np.asarray(sys.D, float)[out, inp]))
