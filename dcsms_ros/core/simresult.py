"""The time series of one batch run (:class:`SimResult`), what :mod:`.engine` returns and the
analysis and exports read."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.supervisor import Transition
from dcsms_ros.core.trip import Trip

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
        Mode changes: the first entry is the starting mode; an instability trip adds
        ``Passive`` at the first sample with the controllers off.
    trip : Trip or None
        The instability trip of this run (:mod:`.trip`), if one happened.
    refused : list of (sample index, label)
        Scheduled switches refused because a trip was latched (as the mode-switch node does).
    excitation : ndarray, shape (K, N, dof), or None
        The excitation wrench added to each stage's controller wrenches (N, N*m), zero from a
        trip on; None when the run had none.
    supervision : list of Transition
        The supervisor's transitions in this block (empty without a supervisor).
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
    trip: Trip | None = None
    refused: list[tuple[int, str]] = field(default_factory=list)
    excitation: Array | None = None
    supervision: list[Transition] = field(default_factory=list)


__all__ = ["SimResult"]
