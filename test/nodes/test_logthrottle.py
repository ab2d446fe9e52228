"""Hot-path log lines (``ros/logthrottle.py``): what a :class:`Throttled` writes reaches
``/rosout`` with its call site, what it drops is never built."""

from __future__ import annotations

import time

from rcl_interfaces.msg import Log
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from dcsms_ros.ros.logthrottle import Throttled


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _declared_here(logger: object, clock: _Clock, severity: LoggingSeverity) -> Throttled:
    return Throttled(logger, 2.0, severity, clock=clock)  # type: ignore[arg-type]


def test_a_throttled_line_reaches_rosout_once_per_period_and_drops_unbuilt(ctx: Context) -> None:
    """Three calls within 2 s write one line, the next after 2 s another; the dropped
    messages are never built; each line carries the node's name, the severity and where the
    throttle was created."""
    node = Node("throttled_talker", context=ctx)
    listener = Node("rosout_listener", context=ctx)
    got: list[Log] = []
    listener.create_subscription(Log, "/rosout", got.append, QoSProfile(
        depth=100, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(listener)
    clock = _Clock()
    built: list[int] = []

    def message(i: int) -> str:
        built.append(i)
        return f"line {i}"

    try:
        end = time.monotonic() + 10.0
        while listener.count_publishers("/rosout") < 2 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        log = _declared_here(node.get_logger(), clock, LoggingSeverity.WARN)
        written = []
        for i, dt in enumerate([0.0, 0.5, 1.9, 0.2, 0.1]):  # at 100.0, .5, 102.4, 102.6, 102.7
            clock.t += dt
            written.append(log(lambda i=i: message(i)))
        assert written == [True, False, True, False, False]
        assert built == [0, 2] and log.suppressed == 3
        end = time.monotonic() + 10.0
        while len([m for m in got if m.name == "throttled_talker"]) < 2 and \
                time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        mine = [m for m in got if m.name == "throttled_talker"]
        assert [m.msg for m in mine] == ["line 0", "line 2"]
        assert all(m.level == Log.WARN for m in mine)
        assert {m.function for m in mine} == {"_declared_here"}
        assert all(m.file.endswith("test_logthrottle.py") for m in mine)
    finally:
        ex.shutdown()
        node.destroy_node()
        listener.destroy_node()


def test_a_level_below_the_loggers_writes_nothing_and_builds_nothing(ctx: Context) -> None:
    """A DEBUG throttle on a logger at INFO: no line, no message built."""
    node = Node("throttled_quiet", context=ctx)
    try:
        built: list[int] = []
        log = Throttled(node.get_logger(), 2.0, LoggingSeverity.DEBUG, clock=_Clock())
        assert not log(lambda: str(built.append(1)))
        assert built == []
    finally:
        node.destroy_node()
