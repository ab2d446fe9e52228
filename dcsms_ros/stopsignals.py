"""The signals that ask a process of this package to stop, and what a terminal's hang-up adds.

SIGINT (Ctrl-C), SIGTERM (``kill``, ``dcsms up`` stopping a child, the death of a child's
parent) and SIGHUP (the terminal closed: an SSH session dropped during a recording) all end a
run the same clean way: a recorder closes its bag, a node publishes its final reports,
``dcsms up`` stops its graph and merges the recorded parts. Python's default for SIGHUP ends
the process at once: a recording's bag stayed unfinished (``OUT.partial``, without metadata)
and ``dcsms up`` left its parts unmerged.

After a hang-up the terminal is gone and every write to it fails (EIO), so the first line the
stop prints (a recorder's report, ``dcsms up``'s summary) would raise in the middle of the stop.
:class:`StopFlag` therefore points the standard output and error that were terminals when it
was made at ``/dev/null`` once SIGHUP arrives; files and pipes (the node logs of ``dcsms up``)
are left alone. No rclpy here: ``dcsms up`` uses it before any ROS import.
"""

from __future__ import annotations

import os
import signal
import time
from typing import Any

#: The signals that ask a process to stop.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def terminal_fds() -> tuple[int, ...]:
    """The standard output and error descriptors (1, 2) that are terminals now."""
    return tuple(fd for fd in (1, 2) if os.isatty(fd))


def leave_terminal(fds: tuple[int, ...]) -> None:
    """Point descriptors ``fds`` at ``/dev/null`` (a hung-up terminal's writes fail)."""
    if not fds:
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in fds:
            os.dup2(null, fd)
    finally:
        os.close(null)


class StopFlag:
    """Signal handler that records the first stop request instead of raising.

    ``signum`` is 0 until a signal arrives; ``at_ns`` is then its system-clock time (ns, the
    clock of DDS receive times: the recorder keeps what was received before it). True once set.
    SIGHUP also moves the output that went to the terminal to ``/dev/null`` (module notes).
    """

    def __init__(self) -> None:
        self.signum = 0
        self.at_ns = 0
        self._terminal = terminal_fds()

    def __call__(self, signum: int, frame: Any) -> None:
        if signum == signal.SIGHUP:
            leave_terminal(self._terminal)
            self._terminal = ()
        if not self.signum:
            self.signum, self.at_ns = signum, time.time_ns()

    def __bool__(self) -> bool:
        return self.signum != 0


__all__ = ["STOP_SIGNALS", "StopFlag", "leave_terminal", "terminal_fds"]
