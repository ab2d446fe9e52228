"""mode_switch's side of the controllers' ``~/enable`` services.

:class:`ControllerClients` calls ``enable(state)`` on several controllers at once and collects
who confirmed; it tells a controller whose service (re)appears, or whose ``boot_ns`` in its
diagnostics changes (a killed process restarted before its old service expired), the state the
current mode wants, so it comes back in the current mode, fading in.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from std_srvs.srv import SetBool

from dcsms_ros.core import topics


class ControllerClients:
    """Enable clients of ``controllers`` created on ``node`` in callback group ``group``."""

    def __init__(self, node: Node, controllers: list[str], group: CallbackGroup) -> None:
        self.node = node
        self.clients = {c: node.create_client(SetBool, topics.LOCAL.enable(c),
                                              callback_group=group) for c in controllers}
        self.ready = dict.fromkeys(controllers, False)
        # a controller killed and restarted keeps its enable service "ready" (DDS liveliness
        # lease): its new boot id in the diagnostics is what tells us it came back
        self.boots: dict[str, str] = {}
        self.names = topics.Names(node.get_namespace())

    def call_all(self, states: dict[str, bool], timeout_s: float,
                 wait_for_service: bool = True) -> dict[str, tuple[bool, str]]:
        """Call ``enable(state)`` on each controller in parallel; (ok, message) per controller.

        A controller whose service is not there is only waited for if ``wait_for_service``
        (a trip does not wait); its message starts with ``not available``.
        """
        deadline = time.monotonic() + timeout_s
        out: dict[str, tuple[bool, str]] = {}
        futures = {}
        pending = list(states)
        # every ready controller gets its request at once; the others are waited for in turn
        while pending:
            for c in [c for c in pending if self.clients[c].service_is_ready()]:
                futures[c] = self.clients[c].call_async(SetBool.Request(data=states[c]))
                pending.remove(c)
            if not pending:
                break
            if not wait_for_service or time.monotonic() >= deadline:
                for c in pending:
                    out[c] = (False, f"not available (no service {self.names.enable(c)})")
                break
            time.sleep(0.01)
        # a controller that was ready gets a fair chance to answer even after a long wait
        deadline = max(deadline, time.monotonic() + 0.25)
        for c, fut in futures.items():
            while not fut.done() and time.monotonic() < deadline:
                time.sleep(0.0005)
            if not fut.done():
                fut.cancel()
                out[c] = (False, f"no reply within {timeout_s:g} s")
            elif fut.result() is None or not fut.result().success:
                out[c] = (False, fut.result().message if fut.result() else "call failed")
            else:
                out[c] = (True, fut.result().message)
        return out

    def tell(self, c: str, state: bool, why: str) -> None:
        """Send ``enable(state)`` to ``c`` without waiting; the answer is logged."""
        fut = self.clients[c].call_async(SetBool.Request(data=state))
        fut.add_done_callback(lambda f: self.node.get_logger().info(
            f"{c} {why}: {f.result().message if f.result() else 'no reply'}"))

    def reconcile(self, want: Callable[[str], bool]) -> None:
        """Tell a controller whose service (re)appeared the state ``want(c)``."""
        for c, client in self.clients.items():
            ready = client.service_is_ready()
            if ready and not self.ready[c]:
                self.tell(c, want(c), "joined")
            elif not ready and self.ready[c]:
                self.node.get_logger().warning(f"{c} left the graph (enable service gone)")
            self.ready[c] = ready

    def on_diagnostics(self, msg: DiagnosticArray, want: Callable[[str], bool]) -> None:
        """A controller reporting a new boot id is a new process: tell it ``want(c)``."""
        for st in msg.status:
            c = self.names.local_status(st.name)
            if c not in self.clients:
                continue
            boot = next((kv.value for kv in st.values if kv.key == "boot_ns"), None)
            if boot is None or self.boots.get(c) == boot:
                continue
            known = c in self.boots
            self.boots[c] = boot
            if known:  # a new process under the same name: give it the current mode's state
                self.tell(c, want(c), "restarted")


__all__ = ["ControllerClients"]
