"""The host's executor and housekeeping timer (ros/executor.py, ros/housekeeping.py): real
rclpy nodes and timers in a private domain."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest
import rclpy.executors as rclpy_executors
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import SingleThreadedExecutor
from rclpy.task import Future

from dcsms_ros.ros.executor import HostExecutor
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.housekeeping import Housekeeper


class Chores(GraphNode):
    """Three periodic jobs: fast (50 ms), slow (200 ms), and an ``async def`` one (100 ms)
    that waits, on its first run, for a future the slow job completes."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("chores", **kwargs)
        self.fast = self.slow = self.waits = self.finished = 0
        self.gate: Future | None = None
        self.housekeeping(0.05, self._fast)
        self.housekeeping(0.2, self._slow)
        # its own group, as mode_switch's judge: while it waits the others go on
        self.housekeeping(0.1, self._waiting, MutuallyExclusiveCallbackGroup())

    def _fast(self) -> None:
        self.fast += 1

    def _slow(self) -> None:
        self.slow += 1
        if self.slow == 3 and self.gate is not None:
            self.gate.set_result(True)

    async def _waiting(self) -> None:
        self.waits += 1
        if self.waits == 1:
            self.gate = Future()
            await self.gate
        self.finished += 1


def _spin(executor: Any, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)


def test_jobs_run_on_their_own_timers_without_a_host(ctx: Any) -> None:
    node = Chores(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    try:
        _spin(ex, 1.0)
        assert len(list(node.timers)) == 3
        assert 15 <= node.fast <= 21 and 4 <= node.slow <= 5
        assert node.finished >= 3
    finally:
        ex.shutdown()
        node.destroy_node()


def test_the_host_runs_every_job_from_one_timer(ctx: Any) -> None:
    """Adopted: one timer left, each job at its own rate, the awaiting job not started again
    while it waits, and it completes once the slow job resolves its future; nothing runs after
    stop()."""
    node = Chores(context=ctx)
    ex = HostExecutor(context=ctx)
    keeper = Housekeeper(ex).keep(node.jobs)
    ex.add_node(node)
    try:
        assert len(list(node.timers)) == 1
        assert keeper.schedule is not None and keeper.schedule.tick_s == 0.05
        _spin(ex, 1.02)
        assert 17 <= node.fast <= 21 and 4 <= node.slow <= 5
        waiting = keeper.jobs[2]
        # runs at 0.1 s (waits until the slow job's third run, ~0.6 s), then from ~0.7 s on
        assert node.waits >= 3 and node.finished == node.waits
        assert waiting.skipped >= 3  # its turns while the first run waited
        ticks = keeper.ticks
        keeper.stop()
        before = (node.fast, node.slow, node.waits)
        _spin(ex, 0.3)
        assert (node.fast, node.slow, node.waits) == before and keeper.ticks == ticks
    finally:
        ex.shutdown()
        node.destroy_node()


@pytest.mark.parametrize("kind", [SingleThreadedExecutor, HostExecutor])
def test_wait_set_builds_per_callback(ctx: Any, monkeypatch: pytest.MonkeyPatch,
                                      kind: type) -> None:
    """rclpy's executor rebuilds its wait set twice per timer callback (its handler's guard
    trigger wakes it again at once); the host's once."""
    builds = [0]
    real = rclpy_executors._rclpy  # counted, not changed

    class CountingWaitSet(real.WaitSet):  # type: ignore[name-defined,misc]
        def __init__(self, *a: Any) -> None:
            builds[0] += 1
            super().__init__(*a)

    class Shim:
        WaitSet = CountingWaitSet

        def __getattr__(self, name: str) -> Any:
            return getattr(real, name)

    monkeypatch.setattr(rclpy_executors, "_rclpy", Shim())
    node = GraphNode("ticker", context=ctx)
    calls = [0]
    node.create_timer(0.05, lambda: calls.__setitem__(0, calls[0] + 1))
    ex = kind(context=ctx)
    ex.add_node(node)
    try:
        _spin(ex, 1.0)
    finally:
        ex.shutdown()
        node.destroy_node()
    per_call = builds[0] / calls[0]
    if kind is HostExecutor:
        assert per_call < 1.5 and ex.dropped_wakeups >= 2 * calls[0] - 2
    else:
        assert per_call > 1.7


def test_host_executor_still_wakes_for_another_thread(ctx: Any) -> None:
    """A wake-up from another thread (a task created there) is not dropped."""
    node = GraphNode("woken", context=ctx)
    ex = HostExecutor(context=ctx)
    ex.add_node(node)
    done = threading.Event()
    try:
        ex.spin_once(timeout_sec=0.1)  # the spinning thread has made handlers by now
        t0 = time.monotonic()
        threading.Timer(0.2, lambda: ex.create_task(done.set)).start()
        while not done.is_set() and time.monotonic() - t0 < 5.0:
            ex.spin_once(timeout_sec=5.0)
        assert done.is_set() and time.monotonic() - t0 < 2.0
    finally:
        ex.shutdown()
        node.destroy_node()
