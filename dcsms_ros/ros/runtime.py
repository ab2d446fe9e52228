"""``main()`` of every node process: build the node, spin it, close it (:func:`run`).

Executor: :class:`.executor.HostExecutor` (rclpy's single-threaded one, without its wake-up
after every callback) for what is not per sample (parameters, services, timers; the node's
periodic jobs on one timer, :mod:`.housekeeping`); a callback that waits for service
replies is an ``async def`` (``mode_switch``'s switch), which the executor runs as a task
between other callbacks. Before
the executor gets the node, its callbacks are wrapped to run under the node's hot-path lock
(:mod:`.serialized`): node code never locks. The per-sample
subscriptions do not go through the executor at all: a node's :class:`~.hotpath.HotPath`
thread serves them from a minimal wait set. Measured (``bench/pingpong.py``, two processes,
5 s, 2026-11-25): that hot path made 7,680-7,820 round trips/s, rclpy's
``EventsExecutor`` driven by a ``spin_once`` loop 7,630-7,960 at the same CPU, the
``SingleThreadedExecutor`` 5,450-6,090 at ~1.7x the CPU; the ``EventsExecutor``'s own
``spin()`` made 1 round trip in 3-6 s. The executor thread wakes a few times a second, so
replacing it is not worth a second executor kind here (docs/performance.md).

Start and shutdown go through :func:`.context.ros_context`: SIGINT and SIGTERM set a flag
(rclpy's handlers are not installed), the spin loop ends, the node publishes its final reports
(:func:`close_nodes`) and is destroyed, and the context is shut down: exit status 0, no
traceback. A configuration error while building the node is one line on stderr and exit
status 2.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Sequence
from contextlib import nullcontext
from typing import Any, Protocol

from rclpy.duration import Duration
from rclpy.executors import Executor
from rclpy.node import Node

from dcsms_ros import graph
from dcsms_ros.errors import DcsmsError
from dcsms_ros.ros.context import (
    HOST_POLL_S,
    POLL_S,
    STOP_EXCEPTIONS,
    ros_context,
    round_ender,
    spin_until,
)
from dcsms_ros.ros.executor import HostExecutor
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.hosted import Hosted, hot_path
from dcsms_ros.ros.hotloop import HostedContext, settle_heap
from dcsms_ros.ros.housekeeping import Housekeeper
from dcsms_ros.ros.serialized import Serialized, hot_lock, serialize

#: Exit status of a configuration error (the CLI's convention).
EXIT_CONFIG = 2


#: SCHED_FIFO priority (1-99) of a node process's hot thread; unset or 0 keeps the default
#: scheduler. ``dcsms up --rt-priority N`` sets it for the control path.
RT_PRIORITY_ENV = graph.RT_PRIORITY_ENV


def rt_priority_from_env() -> tuple[int, str | None]:
    """The SCHED_FIFO priority ``$DCSMS_RT_PRIORITY`` asks for the hot thread (0: none) and a
    warning for a bad value; never raises.

    Only the hot thread gets it (:meth:`HotLoop.start`). The whole process under SCHED_FIFO
    (its executor and Fast DDS's threads inherit the policy) hung 3 of 3 recorded 20 s runs
    of the per-process graph on 2 cores: FIFO threads of equal priority are never time-sliced,
    so a busy executor or DDS writer thread kept a core from the hot threads and starved every
    normal process (the recorder, ``dcsms up``) whose acknowledgements the writers waited for.
    """
    text = os.environ.get(RT_PRIORITY_ENV, "").strip()
    if not text or text == "0":
        return 0, None
    try:
        prio = int(text)
        if not 1 <= prio <= 99:
            raise ValueError
    except ValueError:
        return 0, f"{RT_PRIORITY_ENV}={text!r}: not an integer in 1..99; default scheduler kept"
    return prio, None


#: The CPUs (``taskset -c`` list) of a node process's hot thread; unset: the kernel places it.
#: ``dcsms up --rt-cpus LIST`` sets it for the control path.
RT_CPUS_ENV = graph.RT_CPUS_ENV


def rt_cpus_from_env() -> tuple[frozenset[int], str | None]:
    """The CPUs ``$DCSMS_RT_CPUS`` asks for the hot thread that this process may use (empty:
    the kernel places it) and a warning for a list that is malformed or names a CPU this
    process may not use; never raises.

    On 2 cores with every control-path hot thread on one of them, a controller took 8-27 %
    less CPU a sample (no wake-up crosses cores) and the samples came later (the five share a
    core): docs/performance.md, "Where the hot threads run".
    """
    text = os.environ.get(RT_CPUS_ENV, "").strip()
    try:
        cpus = graph.parse_cpus(text)
    except ValueError as exc:
        return frozenset(), f"{RT_CPUS_ENV}={exc}; the kernel places the hot thread"
    allowed = os.sched_getaffinity(0)
    usable = cpus & allowed
    if usable == cpus:
        return usable, None
    where = f"this process may use {graph.format_cpus(allowed)}"
    if not usable:
        return frozenset(), (f"{RT_CPUS_ENV}={text!r}: none of these CPUs is available "
                             f"({where}); the kernel places the hot thread")
    return usable, (f"{RT_CPUS_ENV}={text!r}: CPUs {graph.format_cpus(cpus - allowed)} are not "
                    f"available ({where}); the hot thread runs on {graph.format_cpus(usable)}")


#: Longest total wait (s) of a process's close for its reliable readers' acknowledgements.
ACK_WAIT_S = 3.0
#: The same after a run that finished by itself (the plant's duration): a recorder on a loaded
#: machine may trail a fast (composed) lockstep run by seconds, and nothing may be lost.
ACK_WAIT_FINISHED_S = 30.0


def wait_acked(pubs: Sequence[Any], total_s: float = ACK_WAIT_S) -> None:
    """Wait until every reader acknowledged what ``pubs`` published, ``total_s`` in all (a
    recorder on a loaded machine may lag; a process that exits earlier loses the rest)."""
    end = time.monotonic() + total_s
    for pub in pubs:
        pub.wait_for_all_acked(Duration(seconds=max(end - time.monotonic(), 0.0)))


def spin_node(node: Node, executor: Executor, stop: Callable[[], bool],
              rt_priority: int = 0, wake: Callable[[], None] | None = None,
              rt_cpus: frozenset[int] = frozenset()) -> None:
    """Spin ``node`` (and its hot path, under SCHED_FIFO ``rt_priority`` if 1-99, on
    ``rt_cpus`` if any) until
    ``stop()`` is true, the node finished, or the context shut down; a failing hot-path
    handler raises here, as a failing callback would.

    ``wake``: a :func:`~.context.round_ender` of ``node`` that the caller also calls when
    ``stop()`` becomes true; the node's finish and a failing hot path call it too, and the loop
    then waits up to :data:`~.context.HOST_POLL_S` per round instead of
    :data:`~.context.POLL_S`.
    """
    serial = serialize(node)  # before the executor can run any of its callbacks
    if isinstance(node, GraphNode):  # its periodic jobs on one timer
        Housekeeper(executor).keep(node.jobs)
    executor.add_node(node)
    if isinstance(node, Hosted):
        node.host_wake = wake
    hot = hot_path(node)
    if isinstance(node.context, HostedContext):
        node.context.held = False  # what runs beside the node is attached by now
    if hot is not None:
        settle_heap()
        hot.start()
        if hot.loop is not None:
            hot.loop.on_error = wake
        warning = None
        if hot.loop is not None:
            hot.loop.cpus = rt_cpus
            warning = hot.loop.prioritize(rt_priority)
        if warning:
            node.get_logger().warning(warning)

    def done() -> bool:
        if hot is not None and hot.error is not None:
            raise hot.error
        return stop() or (isinstance(node, Hosted) and node.finished)

    try:
        spin_until(executor, done, poll_s=POLL_S if wake is None else HOST_POLL_S)
    finally:
        report_hold(node, serial)


def report_hold(node: Node, serial: Serialized | None) -> None:
    """Log, at exit, the longest time one of ``node``'s executor callbacks held its hot loop
    (a sample waits as long: :mod:`.serialized`)."""
    if serial is None or not serial.calls:
        return
    node.get_logger().info(f"longest executor callback under the hot-path lock: "
                           f"{serial.longest_s * 1e3:.3f} ms ({serial.longest}; "
                           f"{serial.calls} calls)")


def quiesce(executor: Executor, node: Node, timeout_s: float = 2.0) -> None:
    """Stop scheduling ``node``'s callbacks and let the running ones finish completely.

    The package's executors are single-threaded, so no callback runs while this is called
    from the spinning thread; the wait covers an executor with worker threads (rclpy's
    multi-threaded one, which the composed process used before): a worker triggers the
    executor's guard condition *after* its callback's work is accounted for, and if
    ``shutdown()`` has destroyed that guard in between, the task stores an ``InvalidHandle``
    that rclpy prints at exit ("The following exception was never retrieved: cannot use
    Destroyable ...").
    """
    executor.remove_node(node)
    tracker = getattr(executor, "_work_tracker", None)  # rclpy >= Jazzy
    if tracker is not None:
        tracker.wait(timeout_s)
    time.sleep(0.05)  # the trailing guard-condition trigger of the last callback


def config_error(exc: DcsmsError) -> int:
    """Print a configuration error as one line; returns :data:`EXIT_CONFIG`."""
    print(f"dcsms: error: {exc}", file=sys.stderr, flush=True)
    return EXIT_CONFIG


def close_nodes(nodes: Sequence[Node], before_destroy: Callable[[], object] = lambda: None,
                ) -> None:
    """Each node's ``final_reports()``, one shared wait for their acknowledgements,
    ``before_destroy()`` (also if the reports failed), destroy.

    The wait is shared because a reader acknowledges only at the writer's next periodic
    heartbeat: with Fast DDS's 3 s, waiting node by node cost composed graphs 3 s per node at
    exit (14 s for Table 1) and one shared deadline still up to 3 s; the package's profile
    heartbeats every 100 ms (``loopback_profile.xml``). The budget is
    :data:`ACK_WAIT_FINISHED_S` after a run that finished by itself.
    """
    pubs: list[Any] = []
    try:
        for node in nodes:
            if isinstance(node, Hosted):
                lock = hot_lock(node)  # a hot loop still draining shares the node's state
                with lock if lock is not None else nullcontext():
                    pubs += node.final_reports()
        finished = any(isinstance(node, Hosted) and node.finished for node in nodes)
        wait_acked(pubs, ACK_WAIT_FINISHED_S if finished else ACK_WAIT_S)
    finally:
        before_destroy()
    for node in nodes:
        hot = hot_path(node)
        node.destroy_node()
        if hot is not None:
            # after its DDS readers went: a writer would send on DDS to a reader without a lane
            hot.close_lanes()


class Attachment(Protocol):
    """Something a node's process runs beside the node (the node's own recorder of a
    recorded run, :mod:`dcsms_ros.nodes.recorder_part`): made once the node exists, before it
    spins; finished after the node's hot loop ended and its final reports went out, before
    the node is destroyed."""

    def finish(self) -> object:
        """Close (the node has stopped publishing)."""

    def abort(self) -> None:
        """Give up (the node failed before it ran)."""


def run(factory: Callable[..., Node], args: Sequence[str] | None = None,
        attach: Callable[[Node], Attachment | None] | None = None) -> int:
    """Create a node with ``factory(context=...)``, spin it, shut down cleanly.

    Parameters
    ----------
    factory : callable
        Called as ``factory(context=ctx)``; returns the node.
    args : sequence of str, optional
        Command line (default ``sys.argv``), ``--ros-args`` included.
    attach : callable, optional
        ``attach(node)``: what runs beside the node (None: nothing); may raise
        :class:`~dcsms_ros.errors.DcsmsError` as a configuration error.

    Returns
    -------
    int
        0 after a signal or a normal finish, 2 after a configuration error.
    """
    rt_priority, rt_warning = rt_priority_from_env()
    rt_cpus, cpus_warning = rt_cpus_from_env()
    status = 0
    with ros_context(args, signals=True, context=HostedContext()) as ros:
        node: Node | None = None
        extra: Attachment | None = None
        ran = False
        try:
            node = factory(context=ros.context)
            extra = attach(node) if attach is not None else None
            for warning in (rt_warning, cpus_warning):
                if warning:
                    node.get_logger().warning(warning)
            executor = HostExecutor(context=ros.context)
            wake = round_ender(node)
            ros.wakers.append(wake)
            try:
                ran = True
                spin_node(node, executor, lambda: bool(ros.stop), rt_priority, wake, rt_cpus)
            finally:
                executor.shutdown(timeout_sec=2.0)
        except DcsmsError as exc:
            status = config_error(exc)
        except STOP_EXCEPTIONS:
            pass
        finally:
            # before the node's entities go: a failure in rclpy's teardown must not cost the
            # node's part of the bag
            closing = _Finish(extra, ran)

            def saved() -> None:
                closing()
                ros.bound_teardown()

            try:
                if node is not None:
                    hot = hot_path(node)
                    if hot is not None:
                        hot.stop()  # the hot thread ends before the node's entities go
                    close_nodes([node], saved)
            finally:
                closing()
            status = closing.status or status
    return status


class _Finish:
    """Finish (or, if the node never ran, abort) an attachment, once; ``status`` is a
    configuration-error status if finishing failed, else 0."""

    def __init__(self, extra: Attachment | None, ran: bool) -> None:
        self.extra, self.ran, self.status = extra, ran, 0

    def __call__(self) -> None:
        extra, self.extra = self.extra, None
        if extra is None:
            return
        if not self.ran:
            extra.abort()
            return
        try:
            extra.finish()
        except DcsmsError as exc:
            self.status = config_error(exc)


def main_for(factory: Callable[..., Node],
             attach: Callable[[Node], Attachment | None] | None = None) -> Callable[..., None]:
    """A ``main(args=None)`` entry point for ``factory`` (and ``attach``, see :func:`run`)
    that exits with :func:`run`'s status."""

    def main(args: Sequence[str] | None = None) -> None:
        sys.exit(run(factory, args, attach))

    return main
