"""The message objects the nodes still build: stamps and diagnostics.

The per-sample messages never become objects (:mod:`dcsms_ros.cdr` serialises them); what is
left is published rarely (``/clock``, ``/diagnostics``). Stamps are integer nanoseconds so that
lockstep matching is exact.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.node import Node

from dcsms_ros.cdr import NS
from dcsms_ros.core.topics import status_name


def to_stamp(ns: int) -> Time:
    """Integer nanoseconds -> builtin_interfaces/Time."""
    return Time(sec=ns // NS, nanosec=ns % NS)


def sample_ns(k: int, rate_hz: float) -> int:
    """Stamp of sample ``k`` at ``rate_hz``: ``round(k / rate_hz)`` in ns (exact, no drift)."""
    return int(round(k * NS / rate_hz))


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
