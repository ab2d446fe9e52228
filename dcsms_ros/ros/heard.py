"""Real time: a (re)started controller's fade begins once the plant has taken one of its forces.

A controller joining a running plant fades its loop in from zero over ``control.fade_time_s``.
The fade must start when its forces reach the plant, not before: a fade that ran unheard
arrives as a step. Its writer's match does not tell it: DDS matches the writer and the reader
separately, and a reader drops the samples of a writer it has not matched yet (at start-up the
decoupling's reader matched the plant's writer 0.76-1.28 s late in 5 of 10 per-process runs,
docs/performance.md). So the plant says what it heard: when it takes a force of a controller
whose process it has not heard yet (the ``<controller>/boot`` value, latched), it publishes
that value on ``plant/heard/<controller>`` (std_msgs/Int64, latched); the controller starts
its fade once the value is its own boot. It publishes zero forces until then, which is what
the plant takes.

Another actuator node (a rig's driver, ``force_reader`` not the plant) does not echo: the
controller then starts on its writer's match (:mod:`.controller_node`).
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import partial

from rclpy.node import Node
from std_msgs.msg import Int64

from dcsms_ros.core import topics
from dcsms_ros.ros import qos


class HeardEcho:
    """The plant's side: ``plant/heard/<controller>`` once per controller process.

    Parameters
    ----------
    node : Node
        The plant (its executor delivers the boots, its hot thread calls :meth:`took`).
    controllers : iterable of str
        Controller ids (each publishes ``<id>/boot``).
    """

    def __init__(self, node: Node, controllers: Iterable[str]) -> None:
        cids = list(controllers)
        self.boot = dict.fromkeys(cids, 0)
        self.told = dict.fromkeys(cids, 0)
        #: True while a boot is not echoed yet: :meth:`took` is called only then (three forces
        #: a sample). Set by the executor after the boot it learnt, cleared by the hot thread
        #: before it looks at the boots again, so neither side can hide the other's change.
        self.pending = False
        self.pubs = {c: node.create_publisher(Int64, topics.LOCAL.heard(c), qos.latched())
                     for c in cids}
        for c in cids:
            node.create_subscription(Int64, topics.LOCAL.boot(c), partial(self._on_boot, c),
                                     qos.latched())

    def _on_boot(self, cid: str, msg: Int64) -> None:
        self.boot[cid] = int(msg.data)
        self.pending = True

    def took(self, cid: str) -> None:
        """The plant took a force of ``cid``: echo its boot if not told yet (the caller may
        skip it while not :attr:`pending`)."""
        boot = self.boot.get(cid, 0)
        if boot and boot != self.told[cid]:
            self.told[cid] = boot
            self.pubs[cid].publish(Int64(data=boot))
        self.pending = False
        self.pending = any(b and b != self.told[c] for c, b in self.boot.items())


class HeardBy:
    """A controller's side: has the plant taken a force of this process?

    Parameters
    ----------
    node : Node
        The controller (its executor delivers the echo).
    cid : str
        Its controller id.
    boot_ns : int
        Its process's boot value (what it published on ``<cid>/boot``).
    """

    def __init__(self, node: Node, cid: str, boot_ns: int) -> None:
        self.boot_ns = boot_ns
        self.echo = 0
        node.create_subscription(Int64, topics.LOCAL.heard(cid), self._on_echo, qos.latched())

    def _on_echo(self, msg: Int64) -> None:
        self.echo = int(msg.data)

    @property
    def heard(self) -> bool:
        """True once the plant echoed this process's boot."""
        return self.echo == self.boot_ns


__all__ = ["HeardBy", "HeardEcho"]
