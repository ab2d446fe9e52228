"""Several service calls made at once and awaited by an ``async def`` callback.

mode_switch switches every controller of a mode atomically: it sends each its request at once
and needs every reply (or the lack of one) before it answers its own caller or, in lockstep,
before the plant hears the trip verdict. :func:`call_together` is a coroutine: the callback that
awaits it is suspended (rclpy's executor runs it as a task) while the executor takes the
replies, so it needs no second thread, no lock and no polling of the replies. The deadline is a
one-shot timer; a service that is not there yet is looked for every :data:`SERVICE_POLL_S`
(rclpy has no event for a service that appears).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.client import Client
from rclpy.node import Node
from rclpy.task import Future

from dcsms_ros.ros import gilfree
from dcsms_ros.ros.clock import steady_timer

#: Seconds between looks for a service that is not there yet.
SERVICE_POLL_S = 0.01
#: Seconds a request already sent may still take after the deadline (a fair chance to answer
#: after a long wait for another service).
REPLY_GRACE_S = 0.25


async def settled(node: Node, futures: list[Future], timeout_s: float) -> None:
    """Return once every future in ``futures`` is done or ``timeout_s`` passed (a one-shot
    timer on ``node``; the awaiting task is resumed by the executor that completes them)."""
    if all(f.done() for f in futures):
        return
    done = Future()

    def settle(_: Any = None) -> None:
        if not done.done():
            done.set_result(None)

    def check(_: Any) -> None:
        if all(f.done() for f in futures):
            settle()

    for f in futures:
        f.add_done_callback(check)
    timer = steady_timer(node, max(timeout_s, 1e-6), settle, ReentrantCallbackGroup())
    try:
        await done
    finally:
        node.destroy_timer(timer)


async def pause(node: Node, seconds: float) -> None:
    """Return after ``seconds`` (a one-shot timer on ``node``)."""
    await settled(node, [Future()], seconds)


async def call_together(node: Node, clients: Mapping[str, Client], requests: Mapping[str, Any],
                        timeout_s: float,
                        wait_for_service: bool = True) -> dict[str, tuple[bool, str]]:
    """Call ``clients[k]`` with ``requests[k]`` for every key of ``requests``, in parallel;
    (ok, message) per key, from the reply's ``success`` and ``message``.

    Parameters
    ----------
    node : Node
        The clients' node (its executor takes the replies and runs the deadline timer).
    clients : mapping of str to Client
        The service clients.
    requests : mapping of str to request
        The request per key of ``clients``.
    timeout_s : float
        Seconds to wait for services and replies (a request sent gets at least
        :data:`REPLY_GRACE_S` more).
    wait_for_service : bool
        Wait up to ``timeout_s`` for a service that is not there (False: give up at once); its
        message starts with ``not available``.
    """
    deadline = time.monotonic() + timeout_s
    out: dict[str, tuple[bool, str]] = {}
    futures: dict[str, Future] = {}
    pending = list(requests)
    # every ready service gets its request at once; the others are waited for in turn
    while pending:
        for k in [k for k in pending if gilfree.service_is_ready(node, clients[k])]:
            futures[k] = clients[k].call_async(requests[k])
            pending.remove(k)
        if not pending:
            break
        if not wait_for_service or time.monotonic() >= deadline:
            for k in pending:
                out[k] = (False, f"not available (no service {clients[k].srv_name})")
            break
        await pause(node, min(SERVICE_POLL_S, max(deadline - time.monotonic(), 0.0)))
    deadline = max(deadline, time.monotonic() + REPLY_GRACE_S)
    await settled(node, list(futures.values()), deadline - time.monotonic())
    for k, fut in futures.items():
        if not fut.done():
            fut.cancel()
            out[k] = (False, f"no reply within {timeout_s:g} s")
        elif fut.result() is None or not fut.result().success:
            out[k] = (False, fut.result().message if fut.result() else "call failed")
        else:
            out[k] = (True, fut.result().message)
    return out


__all__ = ["REPLY_GRACE_S", "SERVICE_POLL_S", "call_together", "pause", "settled"]
