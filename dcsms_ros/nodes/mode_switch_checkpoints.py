"""mode_switch's side of the lockstep trip checkpoints: the plant's question, the verdict.

In lockstep the plant asks about each checkpoint (``trip/check``, the stamp of its last sample)
once every controller answered that sample, and waits for the verdict (``trip/checked``). The
checkpoint is judged once every watched stream holds its samples through the stamp (their
delivery may trail the question), and answered once the controllers followed what it
decided, so a trip lands on the batch engine's sample. Served by mode_switch's hot loop (its
tick), or with the hot path off by a retry timer of the executor.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.node import Node
from rclpy.timer import Timer
from std_msgs.msg import Header

from dcsms_ros.cdr import header_bytes, read_header
from dcsms_ros.core import topics
from dcsms_ros.nodes.mode_switch_supervisor import TableWatch
from dcsms_ros.ros import qos
from dcsms_ros.ros.clock import steady_timer
from dcsms_ros.ros.hotpath import HotPath

#: Seconds between looks for the samples of an asked checkpoint that are still in flight.
RETRY_S = 0.0002


class CheckpointAnswers:
    """The question and the verdict of every lockstep trip checkpoint.

    Parameters
    ----------
    node : Node
        mode_switch (its publisher, subscription and retry timer).
    hot : HotPath
        Its hot path (tick and wake-up).
    watch : TableWatch
        The streams a checkpoint needs complete.
    judge : callable
        ``judge(stamp_ns)``: judge the checkpoint, whose samples were just drained into
        ``watch`` (may set a mode the controllers must follow).
    following : callable
        ``following()``: True while the controllers still have to follow a decision.
    verdict : callable
        ``verdict()``: ``tripped`` or ``ok``, sent with the answer.
    timeout_s : callable
        ``timeout_s()``: the plant's lockstep timeout (s; it asks again after it).
    """

    def __init__(self, node: Node, hot: HotPath, watch: TableWatch,
                 judge: Callable[[int], None], following: Callable[[], bool],
                 verdict: Callable[[], str], timeout_s: Callable[[], float]) -> None:
        self.hot, self.watch = hot, watch
        self.judge, self.following, self.verdict, self.timeout_s = (judge, following, verdict,
                                                                    timeout_s)
        self.asked = -1  # the checkpoint stamp the plant waits for
        self.judged = -1  # ... the newest checkpoint judged
        self.answered = -1
        self.pub = hot.publisher(Header, topics.LOCAL.trip_checked, qos.stream_pub(True))
        hot.subscribe(Header, topics.LOCAL.trip_check, self._on_check, qos.stream_sub(True),
                      raw=True)
        self._retry: Timer | None = None
        self._retry_until = 0.0
        if not hot.on:  # the executor retries what the hot loop's tick would
            self._retry = steady_timer(node, RETRY_S, self._retry_check)
            self._retry.cancel()
        hot.set_tick(self.tick)

    def _on_check(self, buf: bytes) -> None:
        """The plant waits for the verdict on the checkpoint ending at ``stamp``."""
        stamp, _ = read_header(buf)
        if stamp <= self.answered:
            self._answer(stamp)  # a repeated question (retransmission)
            return
        self.asked = stamp
        if self.tick() is not None and self._retry is not None:
            # hot path off (no tick): look again for the samples still in flight, until the
            # plant's lockstep timeout (it asks again then)
            self._retry_until = time.monotonic() + self.timeout_s()
            self._retry.reset()

    def _retry_check(self) -> None:
        if self.tick() is None or time.monotonic() >= self._retry_until:
            assert self._retry is not None
            self._retry.cancel()

    def tick(self) -> float | None:
        """Judge the asked checkpoint once its samples are in (else: look again in
        :data:`RETRY_S`); answer once the controllers followed (:meth:`followed`)."""
        if self.asked < 0:
            return None
        if self.judged < self.asked:
            self.watch.drain()
            if not self.watch.complete(self.asked):
                return RETRY_S
            self.judged = self.asked
            self.judge(self.asked)
        if self.following():
            return None
        self._answer(self.asked)
        self.asked = -1
        return None

    def followed(self) -> None:
        """The controllers followed the decision: answer the waiting plant now."""
        if self.asked < 0:
            return
        if self.hot.on:
            self.hot.wake()  # the hot loop's tick answers
        else:
            self.tick()

    def _answer(self, stamp: int) -> None:
        self.answered = max(self.answered, stamp)
        self.pub.publish(header_bytes(stamp, self.verdict()))


__all__ = ["RETRY_S", "CheckpointAnswers"]
