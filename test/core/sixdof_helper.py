"""A small self-contained 6dof, two-stage configuration for the core tests."""

from __future__ import annotations

import math
from typing import Any

from dcsms_ros.core.config import SystemConfig, config_from_flat


def _triangle(r: float, z: float) -> list[tuple[float, float, float]]:
    return [(r * math.cos(math.radians(90 + 120 * i)), r * math.sin(math.radians(90 + 120 * i)),
             z) for i in range(3)]


def _six(r: float, z: float) -> tuple[list[float], list[float]]:
    """Three vertical and three tangential transducers on a triangle: rank 6."""
    pts = _triangle(r, z)
    pos: list[float] = []
    dirs: list[float] = []
    for p in pts:
        pos += list(p)
        dirs += [0.0, 0.0, 1.0]
    for i, p in enumerate(pts):
        a = math.radians(90 + 120 * i)
        pos += list(p)
        dirs += [-math.sin(a), math.cos(a), 0.0]
    return pos, dirs


def sixdof_flat(**overrides: Any) -> dict[str, Any]:
    """Flat params of a 6dof two-stage rig whose reference points differ from the origin."""
    flat: dict[str, Any] = {"plant.fidelity": "6dof"}
    flat["ground.sensors.position"], flat["ground.sensors.direction"] = _six(0.6, 0.0)
    for s, z in (("stage1", 0.2), ("stage2", 0.8)):
        flat[f"{s}.sensors.position"], flat[f"{s}.sensors.direction"] = _six(0.5, z + 0.1)
        flat[f"{s}.actuators.position"], flat[f"{s}.actuators.direction"] = _six(0.4, z)
        flat[f"{s}.mounts.position"] = [c for p in _triangle(0.45, z) for c in p]
        flat[f"{s}.mounts.stiffness"] = [1e5, 1.5e5, 4e5] * 3
        flat[f"{s}.mounts.damping"] = [200.0, 300.0, 650.0] * 3
        flat[f"{s}.com"] = [0.05, -0.02, z + 0.3]
        flat[f"{s}.inertia"] = [300.0, 300.0, 400.0]
    flat.update(overrides)
    return flat


def sixdof_config(**overrides: Any) -> SystemConfig:
    """The 6dof test configuration with dotted-name overrides."""
    return config_from_flat(sixdof_flat(**overrides), "<sixdof test>")
