"""Rigid-body kinematics of mounts, sensors and actuators (paper section 4.2, NOTES.md).

Plain arrays in, arrays out: this module knows nothing of the configuration (``config``
validates a layout with it, ``model`` builds the plant with it).

A twist is ``[vx, vy, vz, wx, wy, wz]`` (m/s, rad/s) at a reference point; a wrench is
``[fx, fy, fz, mx, my, mz]`` (N, N*m) about a reference point. Positions are in metres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.errors import GeometryError

#: Largest condition number accepted for a sensor or drive matrix.
MAX_CONDITION = 1e4

Array = NDArray[np.float64]


def skew(r: Array) -> Array:
    """Cross-product matrix: ``skew(r) @ x == np.cross(r, x)``; r shape (3,) -> (3, 3)."""
    x, y, z = r
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def point_velocity_matrix(offset: Array) -> Array:
    """(3, 6) map from a twist at the reference point to the velocity of a point at ``offset``
    (m) from it: ``v_point = v + w x offset``."""
    return np.hstack([np.eye(3), -skew(np.asarray(offset, dtype=float))])


def twist_transform(from_ref: Array, to_ref: Array) -> Array:
    """(6, 6) map of a twist at ``from_ref`` to the same motion expressed at ``to_ref``."""
    t = np.eye(6)
    t[:3, 3:] = -skew(np.asarray(to_ref, float) - np.asarray(from_ref, float))
    return t


def sensor_matrix(positions: Array, directions: Array, ref: Array) -> Array:
    """Sensor matrix S, shape (n, 6): ``readings = S @ twist_at_ref``.

    Row i is ``[d_i, (r_i - ref) x d_i]`` for a sensor at ``r_i`` measuring along unit ``d_i``.
    """
    p = np.asarray(positions, float).reshape(-1, 3) - np.asarray(ref, float)
    d = np.asarray(directions, float).reshape(-1, 3)
    return np.hstack([d, np.cross(p, d)])


def drive_matrix(positions: Array, directions: Array, ref: Array) -> Array:
    """Drive matrix B, shape (6, n): ``wrench_at_ref = B @ forces``; column i is
    ``[d_i; (r_i - ref) x d_i]``. It is the transpose of :func:`sensor_matrix`."""
    return sensor_matrix(positions, directions, ref).T


def condition(m: Array) -> float:
    """2-norm condition number over the non-trivial singular values (inf if rank-deficient)."""
    s = np.linalg.svd(m, compute_uv=False)
    k = min(m.shape)
    if s.size < k or s[k - 1] <= 1e-12 * max(s[0], 1e-300):
        return float("inf")
    return float(s[0] / s[k - 1])


def check_full_rank(m: Array, what: str, need: int = 6) -> None:
    """Raise :class:`GeometryError` unless ``m`` has rank ``need`` with a sane condition number."""
    rank = int(np.linalg.matrix_rank(m)) if m.size else 0
    if rank < need:
        raise GeometryError(f"{what}: rank {rank} < {need}: the layout cannot resolve all six "
                            f"rigid-body axes")
    c = condition(m)
    if c > MAX_CONDITION:
        raise GeometryError(f"{what}: condition number {c:.3g} exceeds {MAX_CONDITION:g}")


def mount_matrices(positions: Array, stiffness: Array, damping: Array) -> tuple[Array, Array]:
    """Stiffness and damping (6, 6) at the origin of springs at ``positions`` (n, 3) m with
    per-axis ``stiffness`` (n, 3) N/m and ``damping`` (n, 3) N*s/m."""
    k = np.zeros((6, 6))
    c = np.zeros((6, 6))
    for p, kp, cp in zip(positions, stiffness, damping, strict=True):
        t = point_velocity_matrix(np.asarray(p, float))
        k += t.T @ np.diag(kp) @ t
        c += t.T @ np.diag(cp) @ t
    return k, c


def check_stiffness(k: Array, what: str) -> None:
    """Raise :class:`GeometryError` if the mount stiffness ``k`` (6, 6) is singular: the mounts
    leave a rigid-body axis unsupported."""
    s = np.linalg.svd(k, compute_uv=False)
    if s[-1] <= 1e-9 * s[0]:
        raise GeometryError(f"{what}: the stiffness matrix is singular; the mounts cannot hold "
                            f"all six rigid-body axes")
