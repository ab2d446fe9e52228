"""Calls held back until a host has released a node's lock.

A node's executor callbacks run under its hot-path lock (``ros/serialized.py``), so the hot
thread never sees half-updated state. What such a callback must *send* (a diagnostics report:
its message building and a DDS publication, ~0.1-1 ms) should not keep the hot thread waiting
on that lock, so the callback reads its values under the lock and hands the sending to
:meth:`AfterLock.after`; the host runs it once the lock is free. Called anywhere else (a hot
handler, a final report) ``after`` runs the call at once. No ROS here: unit-tested with plain
callables (``test/protocols/test_afterlock.py``).
"""

from __future__ import annotations

from collections.abc import Callable


class AfterLock:
    """A queue of calls for the moment a host releases a node's lock.

    The host brackets each executor callback with :meth:`hold` and :meth:`release` while it
    holds the lock, then runs what :meth:`release` returned.
    """

    def __init__(self) -> None:
        self._queued: list[Callable[[], None]] | None = None

    @property
    def holding(self) -> bool:
        """True between :meth:`hold` and :meth:`release`."""
        return self._queued is not None

    def after(self, fn: Callable[[], None]) -> None:
        """Run ``fn()`` once the host released the lock, or at once when no host callback is
        in progress. ``fn`` runs beside the hot loop, so it must not touch the node's state:
        give it values read under the lock."""
        if self._queued is not None:
            self._queued.append(fn)
        else:
            fn()

    def hold(self) -> None:
        """The host, holding the lock for an executor callback: queue what :meth:`after`
        gets from now on."""
        self._queued = []

    def release(self) -> list[Callable[[], None]]:
        """The host, still holding the lock: the calls queued since :meth:`hold`, oldest
        first (for the host to run once it released the lock); stop queueing."""
        out, self._queued = self._queued or [], None
        return out


__all__ = ["AfterLock"]
