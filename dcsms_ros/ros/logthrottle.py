"""Log lines a hot path may repeat every sample, decided and written without rclpy's caller search.

rclpy's logger (7.1.6) looks up its caller on *every* call, before any filter: for each frame
it reads the source line (``inspect.getframeinfo``) and resolves the file's real path, system
calls included; only then does ``throttle_duration_sec`` drop the message. Measured here, one
throttled ``warning`` costs 250 us of CPU (300 us with ``np.array2string`` in its f-string,
which is built before the call either way): half a sample period at 2 kHz, spent exactly when
a node is already in trouble (a stale input, a saturated actuator, implausible data), which
made it later still. In a py-spy profile of the one-process-per-node graph (a run that the
profiler's own pauses made 37 % late, 30,911 stale forces) that lookup was 7-9 % of the plant's
busy samples and 15-18 % of a controller's. A :class:`Throttled` call that drops costs 0.24 us.

:class:`Throttled` decides first (a monotonic clock read), builds the message only when it will
be written, and writes it through rcutils with the call site found once, where it was created.
It goes where rclpy's logger goes: the console, ``/rosout`` and the log file.
"""

from __future__ import annotations

import inspect
import math
import os
import time
from collections.abc import Callable

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.logging import LoggingSeverity


class Throttled:
    """One log statement, written at most once per ``period_s`` (s, steady clock).

    Parameters
    ----------
    logger : RcutilsLogger
        The node's logger (``node.get_logger()``).
    period_s : float
        Shortest time between two lines, s; the first call always writes.
    severity : LoggingSeverity, optional
        WARN by default.
    clock : callable, optional
        Seconds (monotonic); tests pass their own.

    Attributes
    ----------
    suppressed : int
        Calls dropped by the throttle.
    """

    def __init__(self, logger: RcutilsLogger, period_s: float,
                 severity: LoggingSeverity = LoggingSeverity.WARN,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.period_s = float(period_s)
        self.severity = severity
        self._clock = clock
        self._next = -math.inf
        self.suppressed = 0
        frame = inspect.currentframe()
        caller = frame.f_back if frame is not None else None
        if caller is None:
            self._where = ("<unknown>", "<unknown>", 0)
        else:
            info = inspect.getframeinfo(caller, context=0)
            self._where = (info.function, os.path.realpath(info.filename), info.lineno)

    def __call__(self, message: Callable[[], str]) -> bool:
        """Write ``message()`` unless a line was written less than ``period_s`` ago; returns
        True if written."""
        now = self._clock()
        if now < self._next:
            self.suppressed += 1
            return False
        self._next = now + self.period_s
        if not self.logger.is_enabled_for(self.severity):
            return False
        _rclpy.rclpy_logging_rcutils_log(self.severity, self.logger.name, message(),
                                         *self._where)
        return True


__all__ = ["Throttled"]
