"""The host's executor: rclpy's single-threaded one without a wake-up after every callback.

rclpy 7.1.6 runs each ready entity as a task whose handler triggers the executor's guard
condition twice (once the entity's work is taken, once its callback is done) so that another
thread blocked in the executor's wait rebuilds its wait set with that entity back in it. With a
single thread nobody is blocked there: the next wait-set build comes anyway, and the trigger
only makes that wait return at once, so every callback cost two wake-ups, each rebuilding the
wait set over every entity of the process in Python. A composed process's executor thread
shares the GIL with the real-time driver thread (docs/performance.md, "GIL hand-offs").

:class:`HostExecutor` gives the handlers it makes a guard whose ``trigger()`` does nothing when
called from the spinning thread and triggers the real guard from any other thread (a
``create_task`` or ``wake`` from another thread still wakes it). Everything else is rclpy's.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from rclpy.executors import SingleThreadedExecutor
from rclpy.task import Task


class _HandlerGuard:
    """Stands in for the executor's guard condition inside the handlers it makes."""

    def __init__(self, real: Any) -> None:
        self.real = real
        self.spinner: int | None = None  # thread ident of the spinning thread
        #: triggers dropped (from the spinning thread)
        self.dropped = 0

    def trigger(self) -> None:
        if threading.get_ident() == self.spinner:
            self.dropped += 1
            return
        self.real.trigger()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.real, name)


class HostExecutor(SingleThreadedExecutor):
    """A :class:`~rclpy.executors.SingleThreadedExecutor` whose callbacks do not wake it again
    (see the module notes)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._handler_guard = _HandlerGuard(self._guard)

    @property
    def dropped_wakeups(self) -> int:
        """Guard triggers of handlers that did not wake the executor."""
        return self._handler_guard.dropped

    def _make_handler(self, entity: Any, node: Any, take_from_wait_list: Callable[..., Any]
                      ) -> Task:
        # the handler binds the executor's guard when its task is made: hand it the stand-in
        # (only the spinning thread makes handlers, and it is the one the stand-in silences)
        hg = self._handler_guard
        hg.spinner = threading.get_ident()
        real, self._guard = self._guard, hg  # type: ignore[assignment]
        try:
            return super()._make_handler(entity, node, take_from_wait_list)
        finally:
            self._guard = real


__all__ = ["HostExecutor"]
