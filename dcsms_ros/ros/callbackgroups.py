"""The callback groups of the host: one no executor serves, one whose timers run unlocked.

A hot path's per-sample subscriptions are created in a :class:`DetachedGroup`, so that no
executor puts them in its wait set (the hot loop serves them, :mod:`.hotpath`); a periodic
job that must not hold the node's hot-path lock is a timer of an :class:`UnlockedGroup`
(:mod:`.serialized` leaves it unwrapped).
"""

from __future__ import annotations

from typing import Any

from rclpy.callback_groups import CallbackGroup, ReentrantCallbackGroup


class DetachedGroup(CallbackGroup):
    """A callback group no executor serves: its entities are never put in a wait set."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        return None


class UnlockedGroup(ReentrantCallbackGroup):
    """A callback group whose timers run outside the node's hot-path lock
    (:func:`.serialized.serialize` leaves them unwrapped): for a periodic job that touches
    no node state and is thread-safe on its own (a part recorder's chunk flush, which
    compresses and writes a file and must not hold up the hot thread meanwhile)."""


__all__ = ["DetachedGroup", "UnlockedGroup"]
