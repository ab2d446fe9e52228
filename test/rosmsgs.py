"""rclpy message objects <-> numbers, for the tests that publish or check messages as rclpy
objects (the package itself serialises with :mod:`dcsms_ros.cdr` and builds no such objects).

A body vector has ``dof`` entries: 1 (vertical only, ``z``) or 6 (``x y z rx ry rz``); SI units;
stamps in integer ns.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TwistStamped, WrenchStamped
from sensor_msgs.msg import JointState

from dcsms_ros.cdr import NS


def to_stamp(ns: int) -> Time:
    """Integer nanoseconds -> builtin_interfaces/Time."""
    return Time(sec=ns // NS, nanosec=ns % NS)


def stamp_ns(stamp: Time) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * NS + int(stamp.nanosec)


def _vectors(m: TwistStamped | WrenchStamped) -> tuple[Any, Any]:
    """The two Vector3s of a stamped twist (linear, angular) or wrench (force, torque)."""
    if isinstance(m, TwistStamped):
        return m.twist.linear, m.twist.angular
    return m.wrench.force, m.wrench.torque


def _stamped(m: Any, v: np.ndarray, ns: int, frame: str) -> Any:
    m.header.stamp = to_stamp(ns)
    m.header.frame_id = frame
    a, b = _vectors(m)
    if v.shape[0] == 1:
        a.z = float(v[0])
    else:
        a.x, a.y, a.z, b.x, b.y, b.z = (float(x) for x in v[:6])
    return m


def vector_array(m: TwistStamped | WrenchStamped, dof: int) -> np.ndarray:
    """A stamped twist or wrench -> (dof,) array; 1dof keeps ``z`` only."""
    a, b = _vectors(m)
    return np.array([a.z]) if dof == 1 else np.array([a.x, a.y, a.z, b.x, b.y, b.z])


def twist_msg(v: np.ndarray, ns: int, frame: str) -> TwistStamped:
    """Twist (dof,) m/s, rad/s -> TwistStamped in ``frame``."""
    return _stamped(TwistStamped(), v, ns, frame)


def wrench_msg(w: np.ndarray, ns: int, frame: str) -> WrenchStamped:
    """Wrench (dof,) N, N*m -> WrenchStamped in ``frame``."""
    return _stamped(WrenchStamped(), w, ns, frame)


#: TwistStamped / WrenchStamped -> (dof,) array.
twist_array = wrench_array = vector_array


def joint_state(names: Sequence[str], ns: int, velocity: np.ndarray | None = None,
                effort: np.ndarray | None = None) -> JointState:
    """A JointState with channel ``names`` and ``velocity`` (m/s) or ``effort`` (N)."""
    m = JointState()
    m.header.stamp = to_stamp(ns)
    m.name = list(names)
    if velocity is not None:
        m.velocity = velocity.tolist()
    if effort is not None:
        m.effort = effort.tolist()
    return m
