"""How the recorder takes a discovered topic: its message class, whether its messages open
with a stamp (the recorder's time-gap check reads it), the QoS that matches every offered
profile (rosbag2's rule) and the offered profiles as rosbag2 metadata, as ``ros2 bag record``
writes them. Used by :mod:`.recorder` and the per-process part (:mod:`.recorder_part`)."""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dcsms_ros.cdr import CLOCK

_INF_NS = 2**63 - 1


def msg_class(msgtype: str) -> Any:
    """The generated Python class of ``pkg/msg/Name``."""
    pkg, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def is_stamped(cls: Any, msgtype: str) -> bool:
    """True if the first 8 bytes of the body are a stamp (header types and Clock)."""
    if msgtype == CLOCK:
        return True
    fields = list(cls.get_fields_and_field_types().items())
    return bool(fields) and fields[0] == ("header", "std_msgs/Header")


def _dur(ns: int) -> str:
    ns = min(int(ns), _INF_NS)
    return f"{{sec: {ns // 1_000_000_000}, nsec: {ns % 1_000_000_000}}}"


def qos_yaml(profiles: Sequence[Any]) -> str:
    """Offered QoS profiles (rclpy ``QoSProfile``) as rosbag2 v9 metadata YAML, one per
    publisher, as ``ros2 bag record`` writes them."""
    out = [f"- history: {q.history.name.lower()}\n  depth: {int(q.depth)}\n"
           f"  reliability: {q.reliability.name.lower()}\n"
           f"  durability: {q.durability.name.lower()}\n"
           f"  deadline: {_dur(q.deadline.nanoseconds)}\n"
           f"  lifespan: {_dur(q.lifespan.nanoseconds)}\n"
           f"  liveliness: {q.liveliness.name.lower()}\n"
           f"  liveliness_lease_duration: {_dur(q.liveliness_lease_duration.nanoseconds)}"
           f"\n  avoid_ros_namespace_conventions: "
           f"{str(bool(q.avoid_ros_namespace_conventions)).lower()}\n"
           for q in profiles]
    return "".join(out)


def subscription_qos(profiles: Sequence[Any], depth: int) -> QoSProfile:
    """The QoS that matches every offered profile (rosbag2's rule), keep-last ``depth``."""
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in profiles)
    latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in profiles)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


__all__ = ["is_stamped", "msg_class", "qos_yaml", "subscription_qos"]
