"""Several service calls made at once, waited for by a caller that the executor does not run.

mode_switch switches every controller of a mode atomically: it sends each its request at once
and needs every reply (or the lack of one) before it answers its own caller or, in lockstep,
before the plant hears the trip verdict. The replies are taken by the executor's threads; the
caller (a service callback of a multi-threaded executor, or the hot thread) polls the futures,
which needs no free executor thread for done-callbacks (the composed graph has three).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

from rclpy.client import Client

#: Seconds between looks for a service that is not there yet, and for replies.
SERVICE_POLL_S = 0.01
REPLY_POLL_S = 0.0005
#: Seconds a request already sent may still take after the deadline (a fair chance to answer
#: after a long wait for another service).
REPLY_GRACE_S = 0.25


def call_together(clients: Mapping[str, Client], requests: Mapping[str, Any], timeout_s: float,
                  wait_for_service: bool = True) -> dict[str, tuple[bool, str]]:
    """Call ``clients[k]`` with ``requests[k]`` for every key of ``requests``, in parallel;
    (ok, message) per key, from the reply's ``success`` and ``message``.

    Parameters
    ----------
    clients : mapping of str to Client
        The service clients (their replies are taken by an executor on another thread).
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
    futures = {}
    pending = list(requests)
    # every ready service gets its request at once; the others are waited for in turn
    while pending:
        for k in [k for k in pending if clients[k].service_is_ready()]:
            futures[k] = clients[k].call_async(requests[k])
            pending.remove(k)
        if not pending:
            break
        if not wait_for_service or time.monotonic() >= deadline:
            for k in pending:
                out[k] = (False, f"not available (no service {clients[k].srv_name})")
            break
        time.sleep(SERVICE_POLL_S)
    deadline = max(deadline, time.monotonic() + REPLY_GRACE_S)
    for k, fut in futures.items():
        while not fut.done() and time.monotonic() < deadline:
            time.sleep(REPLY_POLL_S)
        if not fut.done():
            fut.cancel()
            out[k] = (False, f"no reply within {timeout_s:g} s")
        elif fut.result() is None or not fut.result().success:
            out[k] = (False, fut.result().message if fut.result() else "call failed")
        else:
            out[k] = (True, fut.result().message)
    return out


__all__ = ["REPLY_GRACE_S", "REPLY_POLL_S", "SERVICE_POLL_S", "call_together"]
