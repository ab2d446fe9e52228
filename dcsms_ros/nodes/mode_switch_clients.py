"""mode_switch's side of the controllers' ``~/enable`` services.

:class:`ControllerClients` calls ``enable(state)`` on several controllers at once and collects
who confirmed; it tells a controller whose service (re)appears, or whose boot id on
``<controller>/boot`` changes (a killed process restarted before its old service expired), the
state the current mode wants, so it comes back in the current mode, fading in.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.task import Future
from std_srvs.srv import SetBool

from dcsms_ros.core import topics
from dcsms_ros.ros import gilfree
from dcsms_ros.ros.services import call_together


class ControllerClients:
    """Enable clients of ``controllers`` created on ``node`` in callback group ``group``."""

    def __init__(self, node: Node, controllers: list[str], group: CallbackGroup) -> None:
        self.node = node
        names = topics.Names(node.get_namespace())  # full names: they are in the messages
        self.clients = {c: node.create_client(SetBool, names.enable(c), callback_group=group)
                        for c in controllers}
        self.ready = dict.fromkeys(controllers, False)
        # a controller killed and restarted keeps its enable service "ready" (DDS liveliness
        # lease): its new boot id is what tells us it came back
        self.boots: dict[str, int] = {}
        #: True while a call of :meth:`call_all` waits for its replies (a switch in progress).
        self.busy = False
        self._idle: Future | None = None

    async def call_all(self, states: dict[str, bool], timeout_s: float,
                       wait_for_service: bool = True) -> dict[str, tuple[bool, str]]:
        """Call ``enable(state)`` on each controller in parallel; (ok, message) per controller.

        Await it from the node's callbacks (they run one at a time). A call made while another
        waits for its replies starts when that one ended: switches never interleave. A
        controller whose service is not there is only waited for if ``wait_for_service`` (a
        trip does not wait); its message starts with ``not available``.
        """
        while self.busy:
            if self._idle is None:
                self._idle = Future()
            await self._idle
        self.busy = True
        try:
            return await call_together(self.node, self.clients, {
                c: SetBool.Request(data=on) for c, on in states.items()}, timeout_s,
                wait_for_service)
        finally:
            self.busy = False
            idle, self._idle = self._idle, None
            if idle is not None:
                idle.set_result(None)

    def tell(self, c: str, state: bool, why: str) -> None:
        """Send ``enable(state)`` to ``c`` without waiting; the answer is logged."""
        fut = self.clients[c].call_async(SetBool.Request(data=state))
        fut.add_done_callback(lambda f: self.node.get_logger().info(
            f"{c} {why}: {f.result().message if f.result() else 'no reply'}"))

    def reconcile(self, want: Callable[[str], bool]) -> None:
        """Tell a controller whose service (re)appeared the state ``want(c)``."""
        for c, client in self.clients.items():
            # without the GIL: composed, rclpy's call made the driver wake up to 0.39 ms late
            ready = gilfree.service_is_ready(self.node, client)
            if ready and not self.ready[c]:
                self.tell(c, want(c), "joined")
            elif not ready and self.ready[c]:
                self.node.get_logger().warning(f"{c} left the graph (enable service gone)")
            self.ready[c] = ready

    def on_boot(self, c: str, boot_ns: int, want: Callable[[str], bool],
                quiet: bool = False) -> None:
        """Controller ``c`` started at ``boot_ns`` (ns since the epoch): a new value under a
        known name is a new process, told ``want(c)`` unless ``quiet``."""
        known = self.boots.get(c)
        self.boots[c] = boot_ns
        if known is not None and known != boot_ns and not quiet:
            self.tell(c, want(c), "restarted")


__all__ = ["ControllerClients"]
