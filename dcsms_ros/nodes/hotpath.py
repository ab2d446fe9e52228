"""Hot path: the control-path subscriptions of a node, served by their own thread.

rclpy's executors rebuild a wait set over *every* entity of a node (6 parameter services, the
enable service, timers, the ``/clock`` subscription of ``use_sim_time``, ...) on each wake-up
and dispatch each callback through a task: ~0.1-0.2 ms of Python per message, the dominant cost
of a lockstep step (measured: ``bench/graph_bench.py``, README "Performance"). Here a node's
per-sample subscriptions are created in a callback group that no executor ever waits on
(:class:`DetachedGroup`); one thread per node waits on a minimal wait set holding just those
subscriptions and a stop guard condition (as :func:`rclpy.wait_for_message` does), takes every
queued message with ``take_message`` and runs its handler under the node's lock. Services,
parameters, timers and ``/clock`` stay with the normal executor, which now wakes rarely.

``DCSMS_HOT_PATH=0`` in the environment turns it off: the subscriptions are then ordinary
executor subscriptions with the same handlers (the benchmark compares both in one run).
Subscriptions that nobody needs to serve per sample (observers such as the trip monitor) can
be created detached and emptied in batches by :meth:`HotPath.drain` from a periodic timer.
"""

from __future__ import annotations

import contextlib
import os
import threading
import traceback
from collections.abc import Callable
from contextlib import ExitStack
from typing import Any

from rclpy.callback_groups import CallbackGroup
from rclpy.guard_condition import GuardCondition
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription

#: Wake-up of the hot thread when nothing arrives (s): bounds the reaction to a stop request.
IDLE_S = 0.1


def enabled() -> bool:
    """Whether the hot path is on (default) or turned off by ``DCSMS_HOT_PATH=0``."""
    return os.environ.get("DCSMS_HOT_PATH", "1") not in ("0", "false", "no", "off")


class DetachedGroup(CallbackGroup):
    """A callback group no executor serves: its entities are never put in a wait set."""

    def can_execute(self, entity: Any) -> bool:
        return False

    def beginning_execution(self, entity: Any) -> bool:
        return False

    def ending_execution(self, entity: Any) -> None:
        return None


class HotPath:
    """The per-sample subscriptions of ``node`` and the thread that serves them.

    Parameters
    ----------
    node : Node
        Owner of the subscriptions (they are its entities: graph introspection and
        ``destroy_node`` see them as usual).
    lock : threading.Lock or RLock
        Held while a handler (or ``tick``) runs; the node's executor callbacks that touch the
        same state take it too.
    """

    def __init__(self, node: Node, lock: Any) -> None:
        self.node = node
        self.lock = lock
        self.on = enabled()
        self._group = DetachedGroup()
        self._subs: list[tuple[Subscription, Callable[[Any], None]]] = []
        self._tick: Callable[[], float | None] | None = None
        self._stop = False
        self._thread: threading.Thread | None = None
        self._guard: GuardCondition | None = None
        self.error: BaseException | None = None
        self.wakeups = 0
        self.messages = 0

    def subscribe(self, msg_type: Any, topic: str, handler: Callable[[Any], None],
                  qos: QoSProfile, raw: bool = False) -> Subscription:
        """A subscription served by the hot thread (or by the executor when the path is off);
        ``raw``: the handler gets the serialized bytes (see :mod:`.wire`)."""
        if not self.on:
            return self.node.create_subscription(msg_type, topic, handler, qos, raw=raw)
        sub = self.node.create_subscription(msg_type, topic, handler, qos,
                                            callback_group=self._group, raw=raw)
        self._subs.append((sub, handler))
        return sub

    def detached(self, msg_type: Any, topic: str, qos: QoSProfile,
                 raw: bool = False) -> Subscription:
        """A subscription nobody waits on; empty it with :meth:`drain`."""
        return self.node.create_subscription(msg_type, topic, lambda m: None, qos,
                                             callback_group=self._group, raw=raw)

    @staticmethod
    def drain(sub: Subscription, handler: Callable[[Any], None], limit: int = 100000) -> int:
        """Take every queued message of ``sub`` (at most ``limit``), oldest first."""
        n = 0
        with sub.handle:
            while n < limit:
                got = sub.handle.take_message(sub.msg_type, sub.raw)
                if got is None:
                    break
                handler(got[0])
                n += 1
        return n

    def set_tick(self, tick: Callable[[], float | None]) -> None:
        """Call ``tick()`` (under the lock) after every wake-up; it returns the longest wait
        (s) until it must run again, or None for :data:`IDLE_S`. Only with the path on."""
        self._tick = tick

    def start(self) -> None:
        """Start the thread (no-op when off or without subscriptions and tick)."""
        if not self.on or self._thread is not None or not (self._subs or self._tick):
            return
        self._guard = self.node.create_guard_condition(lambda: None,
                                                       callback_group=self._group)
        self.node.context.on_shutdown(self._on_shutdown)
        self._thread = threading.Thread(target=self._run, name=f"hot-{self.node.get_name()}",
                                        daemon=True)
        self._thread.start()

    def wake(self) -> None:
        """Make the thread run ``tick`` now (e.g. when stepping starts)."""
        if self._guard is not None:
            self._guard.trigger()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the thread to end and wait for it (idempotent)."""
        self._stop = True
        if self._thread is not None:
            if self._guard is not None:
                self._guard.trigger()
            self._thread.join(timeout_s)
            self._thread = None

    def _on_shutdown(self) -> None:
        self._stop = True
        if self._guard is not None:
            with contextlib.suppress(Exception):  # the context may be gone already
                self._guard.trigger()

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:  # noqa: BLE001 - re-raised by runtime.spin_until_stopped
            if not self._stop and self.node.context.ok():
                self.error = exc
                self.node.get_logger().error(f"hot path failed:\n{traceback.format_exc()}")

    def _loop(self) -> None:
        assert self._guard is not None
        subs = [s for s, _ in self._subs]
        ws = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, 0, self.node.context.handle)
        with ExitStack() as stack:
            for s in subs:
                stack.enter_context(s.handle)
            stack.enter_context(self._guard.handle)
            guard = self._guard.handle
            table = [(s.handle, s.handle.pointer, s.msg_type, s.raw, h) for s, h in self._subs]
            timeout = IDLE_S
            while not self._stop:
                ws.clear_entities()
                for h, *_ in table:
                    ws.add_subscription(h)
                ws.add_guard_condition(guard)
                ws.wait(max(int(timeout * 1e9), 0))
                self.wakeups += 1
                if self._stop:
                    break
                ready = ws.get_ready_entities("subscription")
                if not ready and subs and subs[0] not in self.node.subscriptions:
                    break  # the node was destroyed without stop(): nothing left to serve
                with self.lock:
                    for h, ptr, typ, raw, handler in table:
                        if ptr not in ready:
                            continue
                        while True:
                            got = h.take_message(typ, raw)
                            if got is None:
                                break
                            self.messages += 1
                            handler(got[0])
                    nxt = self._tick() if self._tick is not None else None
                timeout = IDLE_S if nxt is None else min(max(nxt, 0.0), IDLE_S)

