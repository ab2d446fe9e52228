"""The steady clock of every node's housekeeping timers, built in one place.

Reports, watchdogs, the plant's handshake tick and mode_switch's reconciling run on the steady
(monotonic) wall clock, never on ROS time: no node subscribes to ``/clock`` (``use_sim_time``
false; the samples carry simulated time in their stamps), and a watchdog on simulated time
would move in ``/clock`` steps (docs/performance.md, docs/reliability.md).
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.timer import Timer

#: The one steady clock (a handle on the monotonic clock; shared by every timer).
STEADY = Clock(clock_type=ClockType.STEADY_TIME)


def steady_timer(node: Node, period_s: float, callback: Callable[[], object],
                 group: CallbackGroup | None = None) -> Timer:
    """A timer of ``node`` that calls ``callback`` every ``period_s`` seconds (s) of steady
    wall-clock time, in callback group ``group`` (None: the node's default group)."""
    return node.create_timer(period_s, callback, callback_group=group, clock=STEADY)


__all__ = ["STEADY", "steady_timer"]
