"""Node process start-up and shutdown: the hot loop's GIL switch interval, composed driving, a
node's attachment, what wakes its spin loop."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable

import pytest
import rclpy
from rclpy.node import Node
from std_msgs.msg import Header

from dcsms_ros.ros.hotpath import GIL_SWITCH_S, DrivenContext, HotPath
from dcsms_ros.ros.pausemeter import process_cpu_ns


def test_a_hot_loop_shortens_the_gil_switch_interval(ctx) -> None:
    """Starting a hot loop makes a thread holding the GIL hand it over within GIL_SWITCH_S
    (Python's 5 ms default kept a composed real-time graph 52-61 % late); never lengthens it."""
    old = sys.getswitchinterval()
    node = Node("gil_probe", context=ctx)
    hot = HotPath(node, threading.Lock())
    hot.subscribe(Header, "gil_probe", lambda m: None, 10)
    try:
        sys.setswitchinterval(0.005)
        hot.start()
        assert sys.getswitchinterval() == pytest.approx(GIL_SWITCH_S)
        hot.stop()
        sys.setswitchinterval(1e-5)
        again = HotPath(node, threading.Lock())
        again.subscribe(Header, "gil_probe", lambda m: None, 10)
        again.start()
        assert sys.getswitchinterval() == pytest.approx(1e-5)
        again.stop()
    finally:
        sys.setswitchinterval(old)
        node.destroy_node()


def _ticks_of_a_2ms_loop(ctx, during: Callable[[], None],
                         timed: bool = True) -> list[tuple[float, float]]:
    """(monotonic s, ``woke_late_s``) at every tick of a hot loop whose (``timed``) tick asks
    for 2 ms sleeps, 0.2 s before and after ``during()``."""
    node = Node("woke_late_probe", context=ctx)
    hot = HotPath(node, threading.Lock())
    seen: list[tuple[float, float]] = []

    def tick() -> float:
        seen.append((time.monotonic(), hot.woke_late_s))
        return 0.002

    hot.set_tick(tick, timed=timed)
    try:
        hot.start()
        time.sleep(0.2)
        during()
        time.sleep(0.2)
    finally:
        hot.stop()
        node.destroy_node()
    return seen


def test_a_hot_loop_knows_how_long_nothing_of_its_process_ran_after_a_wait(
        ctx, process_pause) -> None:
    """The whole process stopped through a sleep's end (a paused machine): the first tick
    after it sees ``woke_late_s`` of about the time from that end to the pause's end."""
    spans: list[Callable[[], tuple[float, float]]] = []
    seen = _ticks_of_a_2ms_loop(ctx, lambda: spans.append(process_pause(0.0, 0.05)))
    t0, t1 = spans[0]()
    before = [w for t, w in seen if t < t0]
    assert len(before) > 20 and sorted(before)[len(before) // 2] < 1e-3
    # the sleep in progress at the pause ended within 2 ms after its start; a tick may still
    # run in the tens of us the stop signal takes to land after the pauser read t0 (once
    # in 9 runs: 42 us after it), so the first tick 1 ms after it is the one that waited
    t, late = next((t, w) for t, w in seen if t >= t0 + 0.001)
    # at most from before the pause: the sleep's end may have passed already, unrun, when
    # the stop landed (once: 0.18 ms)
    assert t1 - t0 - 0.005 < late <= t - t0 + 0.001, (late, (t0, t1), t)


def test_a_hot_loop_counts_a_pause_within_its_tick_apart_from_a_late_wake_up(
        ctx, process_pause) -> None:
    """The whole process stopped while a tick worked (a sample's computation): the next tick
    takes about that long from ``take_paused_s``, and its wake-up was not late."""
    node = Node("paused_probe", context=ctx)
    hot = HotPath(node, threading.Lock())
    seen: list[tuple[float, float, float]] = []
    spans: list[Callable[[], tuple[float, float]]] = []
    idle: list[float] = []

    def tick() -> float:
        seen.append((time.monotonic(), hot.woke_late_s, hot.take_paused_s()))
        if len(seen) == 50:
            spans.append(process_pause(0.005, 0.04))
            hot.take_paused_s()  # the pauser's start blocked the tick: not a machine's pause
            t0, c0 = time.monotonic(), process_cpu_ns()
            end = t0 + 0.08
            while time.monotonic() < end:  # the tick's own work, 80 ms
                pass
            idle.append(time.monotonic() - t0 - (process_cpu_ns() - c0) * 1e-9)
        return 0.002

    hot.set_tick(tick, timed=True)
    try:
        hot.start()
        deadline = time.monotonic() + 10.0
        while len(seen) < 80 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        hot.stop()
        node.destroy_node()
    p0, p1 = spans[0]()
    _, woke, paused = seen[50]
    # the pause, and whatever else of the 80 ms the process did not run (other processes,
    # steal), never more than that
    assert p1 - p0 - 0.005 < paused < idle[0] + 0.003, (paused, p1 - p0, idle)
    # the pause ended before the 2 ms sleep after the work began: not counted there again
    assert woke < 0.5 * (p1 - p0), (woke, p1 - p0)
    typical = sorted(x for _, _, x in seen[10:50])[20]
    assert typical < 1e-3, typical  # the median tick paused none


def test_a_loop_without_a_timed_tick_does_not_measure(ctx, process_pause) -> None:
    """Only a loop with a ``timed`` tick (the plant's) pays for the CPU-time reads: another
    reports 0 even after the whole process stopped through its sleep's end."""
    spans: list[Callable[[], tuple[float, float]]] = []
    seen = _ticks_of_a_2ms_loop(ctx, lambda: spans.append(process_pause(0.0, 0.05)),
                                timed=False)
    t0, _ = spans[0]()
    assert any(t >= t0 for t, _ in seen) and all(w == 0.0 for _, w in seen)


def test_a_delay_another_thread_of_the_process_made_is_not_woke_late(ctx, gil_holder) -> None:
    """Another thread's long C call took the GIL through a sleep's end: the loop ran only
    after it, but that thread ran meanwhile, and ``woke_late_s`` leaves out the CPU it used
    (all of the delay, unless other processes took the CPU from it): the process's own
    delay is not the machine's."""
    holds: list[list[float]] = []

    def during() -> None:
        holds.append(gil_holder(0.0))
        while len(holds[0]) < 3:  # the list fills once the hold ended
            time.sleep(0.001)

    seen = _ticks_of_a_2ms_loop(ctx, during)
    t0, _, cpu = holds[0]
    assert cpu > 0.03
    t, late = next((t, w) for t, w in seen if t >= t0)
    assert t >= t0 + cpu - 0.001  # the tick did wait for the holder
    # the sleep in progress at the hold's start ended at most 2 ms after it, and the
    # holder's CPU is the process's: at most the rest of the delay is woke_late
    assert late <= max(t - t0 - cpu, 0.0) + 0.003, (late, t - t0, cpu)


def test_a_driven_context_serves_its_nodes_hot_paths_in_one_thread(ctx, domain: int) -> None:
    """Composed: the hot paths of the nodes on a DrivenContext are its driver's, and a message
    one of them publishes is answered and taken back in the driver thread; a node on a plain
    context (the ``ctx`` fixture) gets a loop of its own."""
    driven = DrivenContext("test-driver")
    rclpy.init(args=[], context=driven, domain_id=domain)
    nodes: list[Node] = []
    paths: list[HotPath] = []
    try:
        a, b = Node("hot_a", context=driven), Node("hot_b", context=driven)
        alone = Node("hot_alone", context=ctx)
        nodes = [a, b, alone]
        got: list[str] = []
        ping = a.create_publisher(Header, "hot_ping", 10)
        pong = b.create_publisher(Header, "hot_pong", 10)
        paths = [HotPath(n, threading.Lock()) for n in nodes]
        ha, hb, hc = paths
        hb.subscribe(Header, "hot_ping", pong.publish, 10)
        ha.subscribe(Header, "hot_pong", lambda m: got.append(threading.current_thread().name),
                     10)
        hc.subscribe(Header, "hot_alone", lambda m: None, 10)
        for h in paths:
            h.start()
        assert ha.loop is driven.driver and hb.loop is driven.driver
        assert ha.driven and hb.driven and not hc.driven
        assert hc.loop is not None and hc.loop is not driven.driver
        driven.driver.start()
        end = time.monotonic() + 10.0
        while not (ping.get_subscription_count() and pong.get_subscription_count()):
            assert time.monotonic() < end, "the nodes never matched"
            time.sleep(0.01)
        while not got and time.monotonic() < end:
            ping.publish(Header())
            time.sleep(0.05)
        assert got and set(got) == {"test-driver"}
    finally:
        driven.driver.stop()
        for h in paths:
            h.stop()  # a driven path's stop leaves the driver to its host: a no-op
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown(context=driven)


#: A node process whose node fails while being destroyed: its attachment (a recorded run's
#: part) is finished first all the same. The node stops itself with SIGINT.
FAILING_TEARDOWN = r"""
import os, signal, sys
from rclpy.node import Node
from dcsms_ros.ros.runtime import run

class Failing(Node):
    def __init__(self, context):
        super().__init__("failing_teardown", context=context)
        self.create_timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))

    def destroy_node(self):
        print("destroy", flush=True)
        raise RuntimeError("teardown failed")

class Part:
    def finish(self):
        print("finish", flush=True)

    def abort(self):
        print("abort", flush=True)

sys.exit(run(Failing, ["x"], lambda node: Part()))
"""


def test_an_attachment_is_finished_before_the_node_is_destroyed(domain: int) -> None:
    out = subprocess.run([sys.executable, "-c", FAILING_TEARDOWN], capture_output=True,
                         text=True, timeout=60, check=False)
    assert out.stdout.split() == ["finish", "destroy"], out.stderr[-2000:]
    assert out.returncode != 0 and "teardown failed" in out.stderr


#: A node process whose hot path ticks from its constructor's ``start()`` on, and an
#: attachment that takes 0.3 s to observe it (as a recorded run's part opens its bag): it
#: prints the ticks it saw at its attachment and at its finish.
ATTACHED_FIRST = r"""
import os, signal, sys, time
from rclpy.node import Node
from dcsms_ros.ros.hosted import Hosted
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.runtime import run

class Ticking(Hosted, Node):
    def __init__(self, context):
        super().__init__("ticking", context=context)
        self.ticks = 0
        self.hot = HotPath(self)
        self.hot.set_tick(self._tick)
        self.hot.start()

    def _tick(self):
        self.ticks += 1
        if self.ticks == 5:
            os.kill(os.getpid(), signal.SIGINT)
        return 0.01

class Part:
    def __init__(self, node):
        self.node = node
        time.sleep(0.3)
        print("attached", node.ticks, flush=True)

    def finish(self):
        print("finished", self.node.ticks, flush=True)

    def abort(self):
        print("abort", flush=True)

sys.exit(run(Ticking, ["x"], Part))
"""


def test_a_node_process_starts_its_hot_loop_once_its_attachment_observes_it(
        domain: int) -> None:
    """A node's constructor asks its hot path to start; under the host (one node per process)
    the loop starts only once the attachment exists, so a recorded run's part sees the node's
    first publication (a controller answered 58 samples before its part observed it)."""
    out = subprocess.run([sys.executable, "-c", ATTACHED_FIRST], capture_output=True,
                         text=True, timeout=60, check=False)
    lines = out.stdout.split("\n")
    assert lines[0] == "attached 0", out.stdout + out.stderr[-2000:]
    assert lines[1].startswith("finished") and int(lines[1].split()[1]) >= 5, out.stdout
    assert out.returncode == 0, out.stderr[-2000:]


#: A node process whose spin loop would poll once a minute: a stop signal, or the node's own
#: finish from another thread (``finish``), must wake it; it prints when it spins.
WOKEN = r"""
import sys, threading
from rclpy.node import Node
from dcsms_ros.ros import runtime
from dcsms_ros.ros.hosted import Hosted

runtime.HOST_POLL_S = 60.0

class Idle(Hosted, Node):
    def __init__(self, context):
        super().__init__("woken", context=context)
        self.timer = self.create_timer(0.2, self._spinning)

    def _spinning(self):
        self.timer.cancel()  # nothing else wakes the executor
        print("spinning", flush=True)
        if sys.argv[1] == "finish":
            threading.Timer(0.2, self.finish).start()

sys.exit(runtime.run(Idle, ["x"]))
"""


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "SIGHUP", "finish"])
def test_what_ends_a_node_process_wakes_its_spin_loop(domain: int, how: str) -> None:
    """The host's spin loop waits up to HOST_POLL_S (60 s here) per round; a stop signal
    (through the signal wake-up pipe) and the node's finish (its host_wake) end it at once."""
    proc = subprocess.Popen([sys.executable, "-c", WOKEN, how], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "spinning"
        if how != "finish":
            proc.send_signal(getattr(signal, how))
        assert proc.wait(timeout=30.0) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


#: A node destroyed before a stop signal reaches the signal thread that wakes its spin loop:
#: exit 1 if any thread raised.
LATE_SIGNAL = r"""
import os, signal, sys, threading, time
from rclpy.node import Node
from dcsms_ros.ros.context import ros_context, round_ender
failed = []
threading.excepthook = lambda args: failed.append(args.exc_value)
with ros_context(["x"], signals=True) as ros:
    node = Node("gone", context=ros.context)
    ros.wakers.append(round_ender(node))
    node.destroy_node()
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.5)
print(repr(failed), flush=True)
sys.exit(1 if failed else 0)
"""


def test_a_stop_signal_after_the_node_is_gone_is_harmless(domain: int) -> None:
    """The waker of a destroyed node does nothing (it raised InvalidHandle in the signal
    thread: a traceback in a node log)."""
    out = subprocess.run([sys.executable, "-c", LATE_SIGNAL], capture_output=True, text=True,
                         timeout=60, check=False)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Traceback" not in out.stderr, out.stderr
