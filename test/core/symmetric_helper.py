"""A 6dof two-stage rig whose vertical axis is Table 1 split over four symmetric mounts."""

from __future__ import annotations

M1, M2, K, C = 988.8, 748.8, 1.2e6, 1960.0


def _square(half: float, z: float) -> list[float]:
    return [c for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)) for c in (sx * half, sy * half, z)]


def _six_sensors(r: float, z: float) -> tuple[list[float], list[float]]:
    pos = [0.0, r, z, -r, -r, z, r, -r, z, 0.0, r, z, 0.0, -r, z, r, 0.0, z]
    dirs = [0, 0, 1, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0, 0, 1, 0]
    return pos, [float(d) for d in dirs]


def symmetric_6dof_flat(com_xy: tuple[float, float] = (0.0, 0.0)) -> dict:
    """Four mounts on a square per stage, each carrying a quarter of Table 1's k and c."""
    flat: dict = {"plant.fidelity": "6dof"}
    flat["ground.sensors.position"], flat["ground.sensors.direction"] = _six_sensors(1.0, 0.0)
    for s, m, z in (("stage1", M1, 0.3), ("stage2", M2, 1.0)):
        flat[f"{s}.mass"] = m
        flat[f"{s}.com"] = [com_xy[0], com_xy[1], z + 0.4]
        flat[f"{s}.inertia"] = [400.0, 500.0, 600.0]
        flat[f"{s}.mounts.position"] = _square(0.6, z)
        flat[f"{s}.mounts.stiffness"] = [K / 8, K / 6, K / 4] * 4
        flat[f"{s}.mounts.damping"] = [C / 8, C / 6, C / 4] * 4
        flat[f"{s}.actuators.position"], flat[f"{s}.actuators.direction"] = _six_sensors(0.5, z)
        flat[f"{s}.sensors.position"], flat[f"{s}.sensors.direction"] = _six_sensors(0.5, z + 0.1)
    return flat
