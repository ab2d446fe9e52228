"""What the host asks of a node it runs, declared rather than guessed.

The host (:func:`.runtime.run` for one process per node, :mod:`dcsms_ros.nodes.container` for
the composed graph) starts a node's hot path, serializes its executor callbacks with it
(:mod:`.serialized`), stops spinning once the node finished, and at exit publishes the node's
final reports and waits for their acknowledgements. A node class mixes in :class:`Hosted` and
overrides what it has; a plain rclpy node (the recorder) has none of it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.intraprocess import SamplePublisher


class Hosted:
    """Mixin of a node the host runs (defaults: no hot path, never finishes by itself, no
    final reports)."""

    #: The node's hot path (per-sample handlers, their thread and lock); None: the executor
    #: serves every callback.
    hot: HotPath | None = None
    #: True once the node ended its run (e.g. the plant after ``duration_s``): the host stops
    #: spinning it.
    finished: bool = False
    #: Set by the host: ends its spin loop's current round from any thread
    #: (:func:`~.context.round_ender`).
    host_wake: Callable[[], object] | None = None

    def finish(self) -> None:
        """Ask the host to stop spinning after the current callback (from any thread)."""
        self.finished = True
        if self.host_wake is not None:
            self.host_wake()

    def final_reports(self) -> list[SamplePublisher]:
        """Publish what is held back and the final counters (the host holds the hot path's
        lock); returns the publishers whose readers should acknowledge before the node goes."""
        return []


def hot_path(node: Any) -> HotPath | None:
    """``node``'s hot path, or None for a node without one."""
    return node.hot if isinstance(node, Hosted) else None


__all__ = ["Hosted", "hot_path"]
