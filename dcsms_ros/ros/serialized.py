"""A node's executor callbacks run one at a time with its hot loop, so node code never locks.

A node with a hot path (:class:`~.hotpath.HotPath`) has two threads on its state: the hot loop
(per-sample handlers and the tick, under the path's lock) and the executor (services, timers,
other subscriptions, guard conditions). Before the executor sees the node, the host wraps the
callback of each of those entities (:func:`serialize`) so that it runs under the same lock: one
callback or handler at a time, whatever thread runs it. An ``async def`` callback (rclpy runs it
as a task, e.g. a service that awaits ``client.call_async``) holds the lock one step at a time,
between two ``await``s, never while it waits. The node's post-set parameter work
(:class:`~.params.NodeConfig`'s ``on_change``) runs under it too (:func:`hot_lock`).

Not under the lock, on purpose: rclpy's own parameter services as a whole. A set request's
validation runs the stability guard, 6-8 ms of loop-model poles on table1, which must not hold
a hot thread; it reads only the node's configuration. Entities created after the host wrapped
the node (the one-shot timers of :mod:`.services`) touch only their own futures.

Each wrapper records the longest time it held the lock (:attr:`Serialized.longest_s`): a
callback that holds it long delays the node's next sample by as much. What a callback hands to
``HotPath.later.after`` (a report's message building and publication) runs after the lock is
released: the executor's thread runs under the normal scheduler, and the longer it holds the
lock the likelier another process preempts it there, with the SCHED_FIFO hot thread waiting.
"""

from __future__ import annotations

import functools
import inspect
import time
import types
from collections.abc import Callable, Coroutine, Generator
from contextlib import contextmanager
from typing import Any

from rclpy.node import Node

from dcsms_ros.ros.callbackgroups import DetachedGroup, UnlockedGroup
from dcsms_ros.ros.hosted import hot_path
from dcsms_ros.ros.hotpath import HotPath

#: Packages of the services every rclpy node creates for itself (parameters, type description).
BUILTIN_SERVICES = ("rcl_interfaces.", "type_description_interfaces.")


def hot_lock(node: Node) -> Any | None:
    """The lock of ``node``'s hot path, or None for a node without one (the recorder)."""
    hot = hot_path(node)
    return hot.lock if hot is not None else None


@types.coroutine
def _suspend(value: Any) -> Generator[Any, Any, Any]:
    """Hand ``value`` (what the inner coroutine yielded) to the task runner; return what it
    sends back."""
    return (yield value)


class Serialized:
    """Wraps callbacks so they run under ``lock`` and records the longest hold.

    Parameters
    ----------
    lock : threading.Lock or RLock
        The node's hot-path lock.
    hot : HotPath, optional
        The node's hot path: what a callback hands to its ``later.after``
        (:class:`~dcsms_ros.protocols.afterlock.AfterLock`) runs once the lock is released.
    """

    def __init__(self, lock: Any, hot: HotPath | None = None) -> None:
        self.lock = lock
        self.hot = hot
        #: Longest single hold (s) and the callback that held it.
        self.longest_s = 0.0
        self.longest = ""
        self.calls = 0

    @contextmanager
    def held(self, name: str) -> Generator[None, None, None]:
        """Hold the lock for the ``with`` block (records how long), then run what the block
        handed to the hot path's ``later.after``."""
        later: list[Callable[[], None]] = []
        with self.lock:
            t0 = time.perf_counter()
            if self.hot is not None:
                self.hot.later.hold()
            try:
                yield
            finally:
                if self.hot is not None:
                    later = self.hot.later.release()
                dt = time.perf_counter() - t0
                self.calls += 1
                if dt > self.longest_s:
                    self.longest_s, self.longest = dt, name
        for fn in later:
            fn()

    def wrap(self, fn: Callable[..., Any], name: str) -> Callable[..., Any]:
        """``fn`` run under the lock; an ``async def`` one step at a time (its signature is
        kept: rclpy reads a subscription callback's arity)."""
        if inspect.iscoroutinefunction(fn):
            coro_fn: Callable[..., Coroutine[Any, Any, Any]] = fn

            @functools.wraps(fn)
            async def stepped(*args: Any) -> Any:
                coro = coro_fn(*args)
                sent: Any = None
                thrown: BaseException | None = None
                while True:
                    with self.held(name):
                        try:
                            out = coro.send(sent) if thrown is None else coro.throw(thrown)
                        except StopIteration as stop:
                            return stop.value
                    try:
                        sent, thrown = await _suspend(out), None
                    except GeneratorExit:  # the task was cancelled: end the inner one too
                        coro.close()
                        raise
                    except BaseException as exc:  # noqa: BLE001 - handed to the inner one
                        sent, thrown = None, exc

            return stepped

        @functools.wraps(fn)
        def plain(*args: Any) -> Any:
            with self.held(name):
                return fn(*args)

        return plain


def serialize(node: Node) -> Serialized | None:
    """Wrap the executor callbacks of ``node`` (timers but those of an
    :class:`~.callbackgroups.UnlockedGroup`, services but rclpy's own, subscriptions not served by
    the hot loop, guard conditions) to run under its hot-path lock; returns the
    wrapper's record, or None for a node without a hot path. Call before the executor gets the
    node."""
    hot = hot_path(node)
    if hot is None:
        return None
    serial = Serialized(hot.lock, hot)
    for tmr in node.timers:
        if not isinstance(tmr.callback_group, UnlockedGroup):
            tmr.callback = serial.wrap(tmr.callback, f"timer {tmr.timer_period_ns / 1e9:g} s")
    for srv in node.services:
        if not srv.srv_type.__module__.startswith(BUILTIN_SERVICES):
            srv.callback = serial.wrap(srv.callback, f"service {srv.srv_name}")
    for sub in node.subscriptions:
        if not isinstance(sub.callback_group, DetachedGroup):
            sub.callback = serial.wrap(sub.callback, f"subscription {sub.topic_name}")
    for gc in node.guards:
        if gc.callback is not None:
            gc.callback = serial.wrap(gc.callback, "guard condition")
    return serial


__all__ = ["BUILTIN_SERVICES", "Serialized", "hot_lock", "serialize"]
