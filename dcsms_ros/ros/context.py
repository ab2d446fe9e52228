"""The one way this package starts and stops rclpy: context, signals, spin loop, shutdown.

Every process that talks ROS goes through :func:`ros_context`: the node processes
(:func:`.runtime.run`), the composed graph (:mod:`dcsms_ros.nodes.container`), the recorder
(:func:`dcsms_ros.nodes.recorder.record`), the supervisor of ``dcsms up``
(:func:`dcsms_ros.cli.monitor.monitoring`) and the service client of ``dcsms mode``. It holds
Jazzy's rules in one place:

- Discovery stays on this machine unless the user chose a range
  (:func:`dcsms_ros.rosenv.keep_discovery_local`), set before the first participant exists.
- Every participant is reached over UDP loopback only, never through a Fast DDS
  shared-memory port (:func:`.transport.loopback_over_udp`), also set before the first
  participant exists: a first send to a shared-memory port can block the sender's whole
  process for 333 ms.
- ``rclpy.init()`` is not a context manager; :func:`ros_context` is, and calls
  ``rclpy.try_shutdown`` on its own :class:`~rclpy.context.Context` however the block ends.
- rclpy's signal handlers are never installed (``SignalHandlerOptions.NO``): on SIGINT they shut
  the context down inside the handler, before the nodes publish their final reports, the
  recorder drains its readers or the composed graph lets its callbacks finish. With
  ``signals=True`` SIGINT, SIGTERM and SIGHUP only set :class:`StopFlag` and :func:`spin_until`
  returns; the previous handlers come back on exit. ``ros2 run`` forwards Ctrl-C to its process
  group only, and ``dcsms up`` signals each child itself, so every node process handles them
  all (:mod:`dcsms_ros.stopsignals`: a closed terminal stops a node as Ctrl-C does).
  With ``signals=False`` the caller's handlers stay (``dcsms up`` keeps its own flag; in
  ``dcsms mode`` Ctrl-C raises ``KeyboardInterrupt``, exit 130).
- A ``main()`` still counts :data:`STOP_EXCEPTIONS` as a normal end (exit status 0):
  ``KeyboardInterrupt``, and ``ExternalShutdownException`` when the context was shut down
  under a spinning executor.
- Once a node process has saved what it must save, its teardown (the nodes destroyed, the
  context shut down) is bounded (:meth:`RosSession.bound_teardown`): rclpy holds the GIL
  through the middleware's teardown of a node, and that teardown hung (mode_switch, in 2 of
  158 runs of a one-process-per-node lockstep test, docs/performance.md), deaf to Ctrl-C and
  to ``dcsms up``'s SIGINT and SIGTERM.
"""

from __future__ import annotations

import faulthandler
import io
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from dcsms_ros.ros.transport import loopback_over_udp
from dcsms_ros.rosenv import keep_discovery_local
from dcsms_ros.stopsignals import STOP_SIGNALS, StopFlag

#: Exceptions that end a ROS process normally: Ctrl-C where rclpy or Python raised it, and a
#: context shut down under a spinning executor.
STOP_EXCEPTIONS: tuple[type[BaseException], ...] = (KeyboardInterrupt, ExternalShutdownException)
#: Longest wait (s) of one :func:`spin_until` round, so a stop request is seen that soon.
POLL_S = 0.1
#: The same for a node process's spin loop, which everything that ends it wakes (a stop
#: signal through :attr:`RosSession.wakers`, the node's finish, a failed hot path): only a
#: safety net. Every round rebuilds the executor's wait set in Python holding the GIL, and the
#: process's hot thread (SCHED_FIFO) that needs the GIL meanwhile waits until the executor's
#: thread, preempted by the control path's other hot threads, runs again: 0.2-0.35 ms.
#: 4 alternating pairs of 20 s per-process runs: late samples 147-254 against 262-328, fewer
#: in every pair. Composed (the executor on the driver's core), 6 pairs showed no gain (late
#: 15-90 against 7-66), so the composed host keeps :data:`POLL_S` (docs/performance.md,
#: "The executor's poll held the GIL").
HOST_POLL_S = 1.0
#: How long a node process's teardown may take once it saved what it must
#: (:meth:`RosSession.bound_teardown`), s: a normal one takes 30-40 ms (mode_switch, one process
#: per node). Below ``dcsms up``'s 5 s between its SIGINT and its SIGTERM (a node saves and
#: exits in ~0.17 s of it: five stopped in turn took 0.83 s), so a hung teardown is reported as
#: one, not as a process that did not stop: at 10 s a CI run's mode_switch, hung there, was
#: aborted after 7 s.
TEARDOWN_BOUND_S = 3.0


@dataclass(frozen=True)
class RosSession:
    """What :func:`ros_context` yields: the initialised context and the stop flag (never set
    when the session does not handle signals).

    ``wakers``: called (from another thread) as soon as a stop signal arrives, before the
    flag is set: a thread blocked in an executor's wait runs Python's signal handler only once
    that wait returns, so a spin loop registers a :func:`round_ender` here.
    """

    context: Context
    stop: StopFlag = field(default_factory=StopFlag)
    wakers: list[Callable[[], object]] = field(default_factory=list)
    #: the bound :meth:`bound_teardown` armed (s), cancelled once the context is shut down
    bounds: list[float] = field(default_factory=list)

    def wake(self) -> None:
        """Call every registered waker."""
        for fn in list(self.wakers):
            fn()

    def bound_teardown(self, seconds: float | None = None) -> None:
        """Give what is left of the ``with`` block (the nodes' destruction, then the context's
        shutdown) at most ``seconds`` (default :data:`TEARDOWN_BOUND_S`); call once nothing
        is left to save. Past it, faulthandler's timer (a C thread: it needs no GIL) writes
        every thread's stack to stderr, the node's log, and ends the process with status 1.
        Nothing is armed where stderr has no file descriptor (an in-process test's capture)."""
        bound = TEARDOWN_BOUND_S if seconds is None else float(seconds)
        try:
            faulthandler.dump_traceback_later(bound, exit=True, file=sys.stderr)
        except (AttributeError, ValueError, OSError, io.UnsupportedOperation):
            return
        self.bounds.append(bound)


class _SignalWake:
    """Calls ``session.wake()`` when a signal arrives: the C-level handler writes its number
    to a pipe at once (:func:`signal.set_wakeup_fd`), wherever the main thread is blocked;
    a thread reads it."""

    def __init__(self, session: RosSession) -> None:
        self._r, self._w = os.pipe()
        os.set_blocking(self._w, False)
        self._old = signal.set_wakeup_fd(self._w, warn_on_full_buffer=False)
        self._thread = threading.Thread(target=self._run, args=(session,), name="signal-wake",
                                        daemon=True)
        self._thread.start()

    def _run(self, session: RosSession) -> None:
        while os.read(self._r, 64):  # empty: the write end is closed
            session.wake()

    def close(self) -> None:
        signal.set_wakeup_fd(self._old)
        os.close(self._w)
        self._thread.join(1.0)
        os.close(self._r)


@contextmanager
def ros_context(args: Sequence[str] | None = None, signals: bool = False,
                context: Context | None = None) -> Iterator[RosSession]:
    """An initialised rclpy context for the ``with`` block, shut down when it ends.

    Parameters
    ----------
    args : sequence of str, optional
        Command line for ``rclpy.init`` (``--ros-args`` ...); None: ``sys.argv``, as rclpy.
        In-process clients pass ``[]`` so that the caller's own options are not read.
    signals : bool
        True: SIGINT, SIGTERM and SIGHUP set the session's :class:`StopFlag` until the block ends
        (a node process, the recorder), and any signal calls its ``wakers`` at once. False:
        leave the process's handlers alone.
    context : Context, optional
        A fresh (uninitialised) context to initialise, e.g. a composed host's
        :class:`~.hotpath.DrivenContext`; default: a new plain one.

    Yields
    ------
    RosSession
        ``context`` for the nodes and executors; ``stop`` for the spin loop.

    Notes
    -----
    Exceptions pass through unchanged (a ``main()`` catches :data:`STOP_EXCEPTIONS`); the
    nodes must be destroyed inside the block, before the context goes.
    """
    keep_discovery_local()
    session = RosSession(context if context is not None else Context())
    old = {s: signal.signal(s, session.stop) for s in STOP_SIGNALS} if signals else {}
    waker = _SignalWake(session) if signals else None
    try:
        with loopback_over_udp():  # held while the caller creates its nodes (the participant)
            rclpy.init(args=None if args is None else list(args), context=session.context,
                       signal_handler_options=SignalHandlerOptions.NO)
            yield session
    finally:
        rclpy.try_shutdown(context=session.context)
        if session.bounds:
            faulthandler.cancel_dump_traceback_later()
        if waker is not None:
            waker.close()
        for s, h in old.items():
            signal.signal(s, h)


def round_ender(node: Node) -> Callable[[], None]:
    """A call, safe from any thread, that ends the current round of an executor spinning
    ``node`` (a guard condition of ``node`` with an empty callback: rclpy's ``Executor.wake``
    only makes the executor rebuild its wait set and wait on until the round's timeout).
    Once the node is destroyed it does nothing: the signal thread may run only after that (the
    stop ran on in the main thread), or a second stop signal may come then, and the trigger
    raised rclpy's ``InvalidHandle`` in that thread (a traceback in mode_switch's log, once in
    a CI run of 2026-11-29)."""
    guard = node.create_guard_condition(lambda: None)

    def end_round() -> None:
        try:
            guard.trigger()
        except _rclpy.InvalidHandle:  # the node is gone: no round left to end
            pass

    return end_round


def spin_until(executor: Executor, done: Callable[[], bool], timeout_s: float | None = None,
               poll_s: float = POLL_S) -> bool:
    """Run ``executor``'s callbacks until ``done()``, the context's shutdown or ``timeout_s``.

    Parameters
    ----------
    executor : Executor
        With its nodes added.
    done : callable
        Asked before every round; it may raise to end the loop with an error (a failed hot
        path does).
    timeout_s : float, optional
        Longest total wait, s; None: no limit.
    poll_s : float
        Longest wait of one round, s (how late a stop request or the deadline is seen).

    Returns
    -------
    bool
        ``done()`` at the end (False after a timeout or a shutdown).
    """
    end = None if timeout_s is None else time.monotonic() + timeout_s
    while not done() and executor.context.ok():
        left = poll_s if end is None else min(poll_s, end - time.monotonic())
        if left <= 0.0:
            break
        executor.spin_once(timeout_sec=left)
    return done()


__all__ = ["HOST_POLL_S", "POLL_S", "STOP_EXCEPTIONS", "STOP_SIGNALS", "TEARDOWN_BOUND_S",
           "RosSession", "StopFlag", "ros_context", "round_ender", "spin_until"]
