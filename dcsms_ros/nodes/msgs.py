"""Message <-> ndarray conversions (SI units throughout, ``header.stamp`` = sample time).

A body vector has ``dof`` entries: 1 (vertical only, ``z``) or 6 (``x y z rx ry rz``).
Stamps are handled as integer nanoseconds so that lockstep matching is exact.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import TwistStamped, WrenchStamped
from numpy.typing import NDArray
from rclpy.node import Node
from sensor_msgs.msg import JointState

from dcsms_ros.core.topics import status_name

Array = NDArray[np.float64]
NS = 1_000_000_000


def stamp_ns(stamp: Time) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return int(stamp.sec) * NS + int(stamp.nanosec)


def to_stamp(ns: int) -> Time:
    """Integer nanoseconds -> builtin_interfaces/Time."""
    return Time(sec=ns // NS, nanosec=ns % NS)


def sample_ns(k: int, rate_hz: float) -> int:
    """Stamp of sample ``k`` at ``rate_hz``: ``round(k / rate_hz)`` in ns (exact, no drift)."""
    return int(round(k * NS / rate_hz))


def _put6(a: Any, b: Any, v: Array) -> None:
    """Write a (dof,) vector into two Vector3s (linear/angular, force/torque); 1dof: ``a.z``."""
    if v.shape[0] == 1:
        a.z = float(v[0])
    else:
        a.x, a.y, a.z, b.x, b.y, b.z = (float(x) for x in v[:6])


def _get6(a: Any, b: Any, dof: int) -> Array:
    """Read two Vector3s back as a (dof,) vector; 1dof keeps ``a.z`` only."""
    if dof == 1:
        return np.array([a.z])
    return np.array([a.x, a.y, a.z, b.x, b.y, b.z])


def twist_msg(v: Array, ns: int, frame: str) -> TwistStamped:
    """Twist (dof,) m/s, rad/s -> TwistStamped in ``frame``."""
    m = TwistStamped()
    m.header.stamp = to_stamp(ns)
    m.header.frame_id = frame
    _put6(m.twist.linear, m.twist.angular, v)
    return m


def twist_array(m: TwistStamped, dof: int) -> Array:
    """TwistStamped -> (dof,) array; 1dof keeps ``linear.z`` only."""
    return _get6(m.twist.linear, m.twist.angular, dof)


def wrench_msg(w: Array, ns: int, frame: str) -> WrenchStamped:
    """Wrench (dof,) N, N*m -> WrenchStamped in ``frame``."""
    m = WrenchStamped()
    m.header.stamp = to_stamp(ns)
    m.header.frame_id = frame
    _put6(m.wrench.force, m.wrench.torque, w)
    return m


def wrench_array(m: WrenchStamped, dof: int) -> Array:
    """WrenchStamped -> (dof,) array; 1dof keeps ``force.z`` only."""
    return _get6(m.wrench.force, m.wrench.torque, dof)


def joint_state(names: Sequence[str], ns: int, velocity: Array | None = None,
                effort: Array | None = None) -> JointState:
    """A JointState with channel ``names`` and ``velocity`` (m/s) or ``effort`` (N)."""
    m = JointState()
    m.header.stamp = to_stamp(ns)
    m.name = list(names)
    if velocity is not None:
        m.velocity = velocity.tolist()
    if effort is not None:
        m.effort = effort.tolist()
    return m


def status(name: str, level: bytes, message: str, values: dict[str, object],
           hardware_id: str = "dcsms") -> DiagnosticStatus:
    """A DiagnosticStatus with ``values`` as key/value strings."""
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])


def node_status(node: Node, level: bytes, message: str, values: dict[str, object],
                sub: str = "") -> DiagnosticStatus:
    """:func:`status` named after ``node``'s full name (``dcsms/plant_simulator``, and
    ``dcsms/plant_simulator/<sub>`` for a part), as /diagnostics tools group them."""
    return status(status_name(node.get_fully_qualified_name(), sub), level, message, values)
