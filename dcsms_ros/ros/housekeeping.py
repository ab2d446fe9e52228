"""The host's housekeeping timer: every node's periodic jobs of a process on one steady timer.

A node declares its periodic jobs (reports, the trip judge, the recorder's flush and
discovery) with :meth:`.graphnode.GraphNode.housekeeping`, which gives it a steady timer of its
own, so a node spun by any executor runs them. The host (:mod:`.runtime` for one node per
process, the composed container for all of them) hands them to a :class:`Housekeeper` after
wrapping the node's callbacks (:mod:`.serialized`) and before the executor gets the node: the
jobs' own timers are destroyed and one timer at the shortest period runs every job that is due
(:class:`~dcsms_ros.protocols.periodic.PeriodicSchedule`), so the jobs due together share one
wake-up of the executor's thread instead of one each. Each wake-up rebuilds rclpy's wait set in
Python under the GIL that a real-time driver thread of the same process waits for
(docs/performance.md, "GIL hand-offs").

A job never runs twice at once (an ``async def`` job that awaits is handed to the executor as a
task, and its next turns are skipped until the task is done), and an exception ends the spin as
a timer callback's would. A job's callback group is not kept: jobs are exclusive with
themselves only, as the nodes' jobs were (each awaiting one in a group of its own, the others
synchronous: one thread runs them one at a time).
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.task import Future
from rclpy.timer import Timer

from dcsms_ros.protocols.periodic import PeriodicSchedule
from dcsms_ros.ros.clock import steady_timer


@dataclass
class Job:
    """One periodic job of a node.

    Attributes
    ----------
    node : Node
    period_s : float
        s.
    timer : Timer or None
        The node's own timer until a host adopts the job.
    runs : int
        Turns taken.
    skipped : int
        Turns skipped while the previous run (a task) was still going.
    task : Future or None
        The executor's task of a run that awaited, until it is done.
    callback : callable or None
        What a turn calls once adopted (the host's wrapper of the timer's callback, if any).
    """

    node: Node
    period_s: float
    timer: Timer | None
    runs: int = 0
    skipped: int = 0
    task: Future | None = None
    callback: Callable[[], object] | None = None


class Housekeeper:
    """Runs the adopted jobs of a process's nodes from one steady timer.

    Parameters
    ----------
    executor : Executor
        The executor that spins the nodes (an awaiting job continues there as a task).
    """

    def __init__(self, executor: Executor) -> None:
        self.executor = executor
        self.jobs: list[Job] = []
        self.schedule: PeriodicSchedule | None = None
        self.timer: Timer | None = None
        #: timer ticks
        self.ticks = 0

    def adopt(self, jobs: Sequence[Job]) -> None:
        """Take ``jobs`` (from :meth:`.GraphNode.housekeeping`) off their own timers; call
        :meth:`start` once every node's jobs are adopted."""
        for job in jobs:
            if job.timer is None:
                continue
            job.callback = job.timer.callback  # the host's wrapper, if it wrapped the node
            job.node.destroy_timer(job.timer)
            job.timer = None
            self.jobs.append(job)

    def keep(self, *jobs: Sequence[Job]) -> Housekeeper:
        """Adopt every list of ``jobs`` and :meth:`start`; returns self."""
        for js in jobs:
            self.adopt(js)
        self.start()
        return self

    def start(self) -> None:
        """Create the one timer (on the first adopted job's node); nothing without jobs."""
        if not self.jobs or self.timer is not None:
            return
        self.schedule = PeriodicSchedule([j.period_s for j in self.jobs], time.monotonic())
        self.timer = steady_timer(self.jobs[0].node, self.schedule.tick_s, self._tick,
                                  ReentrantCallbackGroup())

    def stop(self) -> None:
        """No job runs from now on (the host calls this before it destroys the nodes: the
        one timer lives on one of them but runs the jobs of all)."""
        if self.timer is not None:
            self.jobs[0].node.destroy_timer(self.timer)
            self.timer = None

    def _tick(self) -> None:
        assert self.schedule is not None
        self.ticks += 1
        for j in self.schedule.due(time.monotonic()):
            job = self.jobs[j]
            if job.task is not None:
                if not job.task.done():
                    job.skipped += 1
                    continue
                job.task = None
            job.runs += 1
            assert job.callback is not None
            res = job.callback()
            if inspect.iscoroutine(res):
                self._run(job, res)

    def _run(self, job: Job, coro: Any) -> None:
        """Run ``coro`` to its first suspension here; a suspended one goes on as a task."""
        try:
            coro.send(None)
        except StopIteration:
            return
        job.task = self.executor.create_task(coro)


__all__ = ["Housekeeper", "Job"]
