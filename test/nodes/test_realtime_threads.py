"""The control path's hot thread: its opt-in SCHED_FIFO priority and CPUs (one process per
node and composed)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
from rclpy.node import Node
from std_msgs.msg import Header

from dcsms_ros.cli.deploy import children
from dcsms_ros.graph import RT_CPUS_ENV, define_graph
from dcsms_ros.ros.hotloop import SHARED_CORE_GIL_SWITCH_S, HotLoop
from dcsms_ros.ros.hotpath import GIL_SWITCH_S, DrivenContext, HotPath
from dcsms_ros.ros.runtime import RT_PRIORITY_ENV, rt_cpus_from_env, rt_priority_from_env


def _policy(pid: int, tid: int) -> tuple[int, str]:
    """(scheduling policy, thread name) of thread ``tid`` of process ``pid``."""
    name = Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
    return os.sched_getscheduler(tid), name


@pytest.mark.parametrize("value", [None, "0"])
def test_default_scheduler_when_unset_or_zero(monkeypatch, value: str | None) -> None:
    """No variable (or 0): no priority and nothing said."""
    monkeypatch.delenv(RT_PRIORITY_ENV, raising=False)
    if value is not None:
        monkeypatch.setenv(RT_PRIORITY_ENV, value)
    assert rt_priority_from_env() == (0, None)


@pytest.mark.parametrize("value", ["abc", "100", "-3"])
def test_bad_priority_is_a_warning_not_a_crash(monkeypatch, value: str) -> None:
    """A value outside 1..99 is named in a warning; no priority."""
    monkeypatch.setenv(RT_PRIORITY_ENV, value)
    prio, warning = rt_priority_from_env()
    assert prio == 0 and warning is not None and "1..99" in warning and value in warning


def test_only_the_hot_thread_runs_under_sched_fifo(domain) -> None:
    """A control-path node started with priority 7: its hot thread alone is SCHED_FIFO 7 (or
    the refusal is logged); the main thread, the executor and Fast DDS's threads keep the
    default scheduler, so they are time-sliced with every other process."""
    env = {**os.environ, RT_PRIORITY_ENV: "7"}
    proc = subprocess.Popen([sys.executable, "-m", "dcsms_ros.nodes.sensor_decoupling",
                             "--ros-args", "-r", "__ns:=/rt_probe"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        fifo: list[tuple[int, str]] = []
        deadline = time.monotonic() + 60.0
        while not fifo and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            tasks = [int(t) for t in os.listdir(f"/proc/{proc.pid}/task")]
            policies = {t: _policy(proc.pid, t) for t in tasks}
            fifo = [(t, n) for t, (pol, n) in policies.items() if pol == os.SCHED_FIFO]
        if not fifo:
            proc.send_signal(signal.SIGINT)
            out = proc.communicate(timeout=30)[0]
            assert "refused" in out, out  # not permitted here: said aloud, not silently
            return
        assert len(fifo) == 1, (fifo, policies)
        tid = fifo[0][0]
        assert tid != proc.pid and os.sched_getparam(tid).sched_priority == 7
        others = [n for t, (pol, n) in policies.items() if t != tid]
        assert any(n.startswith("dds.") for n in others), others  # DDS threads exist, normal
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=30)


def test_rt_priority_covers_only_the_control_path(tmp_path, cfg) -> None:
    """--rt-priority and --rt-cpus: plant, decoupling and controllers; not mode_switch (nor
    the recorder)."""
    kids = children(define_graph(cfg), tmp_path / "params.yaml", rt_priority=50,
                    rt_cpus=frozenset({3, 1}))
    got = {k.name: (k.env.get(RT_PRIORITY_ENV), k.env.get(RT_CPUS_ENV)) for k in kids}
    path = ("50", "1,3")
    assert got == {"mode_switch": (None, None), "fb_stage1": path, "fb_stage2": path,
                   "ff_stage1": path, "sensor_decoupling": path, "plant_simulator": path}


@pytest.mark.parametrize("value, cpus", [(None, set()), ("", set()), ("0", {0}),
                                         (" 0 ", {0})])
def test_rt_cpus_from_the_environment(monkeypatch, value: str | None, cpus: set[int]) -> None:
    """Unset or empty: the kernel places the hot thread, nothing said; CPU 0 (always there)."""
    monkeypatch.delenv(RT_CPUS_ENV, raising=False)
    if value is not None:
        monkeypatch.setenv(RT_CPUS_ENV, value)
    assert rt_cpus_from_env() == (cpus, None)


@pytest.mark.parametrize("value, said, cpus", [
    ("abc", "not a CPU list", set()), ("2-1", "not a CPU list", set()),
    ("4096", "none of these CPUs is available", set()),
    ("0,4096", "CPUs 4096 are not available", {0}),
])
def test_bad_rt_cpus_are_a_warning_not_a_crash(monkeypatch, value: str, said: str,
                                               cpus: set[int]) -> None:
    """A malformed list, or one naming no CPU this process may use: named in a warning, and
    the kernel places the thread; a list naming some it may use: those, and a warning."""
    monkeypatch.setenv(RT_CPUS_ENV, value)
    got, warning = rt_cpus_from_env()
    assert got == cpus and warning is not None and said in warning and value in warning


def test_rt_cpus_pin_only_the_hot_thread(domain) -> None:
    """A control-path node started with DCSMS_RT_CPUS naming one CPU: its hot thread alone
    (the SCHED_FIFO one) runs on that CPU; the main thread and Fast DDS's threads keep every
    CPU the process had."""
    allowed = os.sched_getaffinity(0)
    if len(allowed) < 2:
        pytest.skip("one CPU: pinning is not observable")
    cpu = min(allowed)
    env = {**os.environ, RT_PRIORITY_ENV: "7", RT_CPUS_ENV: str(cpu),
           "ROS_DOMAIN_ID": str(domain)}
    proc = subprocess.Popen([sys.executable, "-m", "dcsms_ros.nodes.sensor_decoupling",
                             "--ros-args", "-r", "__ns:=/rt_cpus_probe"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        pinned: dict[int, set[int]] = {}
        deadline = time.monotonic() + 60.0
        while not pinned and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            tasks = [int(t) for t in os.listdir(f"/proc/{proc.pid}/task")]
            pinned = {t: a for t in tasks if (a := os.sched_getaffinity(t)) != allowed}
        assert proc.poll() is None, proc.communicate(timeout=30)[0]
        assert list(pinned.values()) == [{cpu}], pinned
        (tid,) = pinned
        assert tid != proc.pid
        fifo = os.sched_getscheduler(tid) == os.SCHED_FIFO
        others = [_policy(proc.pid, t) for t in tasks if t != tid]
        assert all(pol != os.SCHED_FIFO for pol, _ in others), others
        assert fifo or os.geteuid() != 0  # root is granted SCHED_FIFO: the pinned one has it
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=30)


@contextlib.contextmanager
def _driver(domain: int, name: str, **settings: Any) -> Iterator[HotLoop]:
    """The driver of a DrivenContext serving one probe node's hot path, ``settings`` (its
    attributes) set before the caller starts it; afterwards everything is torn down and the
    calling thread's CPUs and the GIL switch interval are restored."""
    me = threading.get_native_id()
    mine = os.sched_getaffinity(me)
    interval = sys.getswitchinterval()
    driven = DrivenContext(f"{name}-driver")
    for key, value in settings.items():
        setattr(driven.driver, key, value)
    rclpy.init(args=[], context=driven, domain_id=domain)
    node = Node(name, context=driven)
    hot = HotPath(node, threading.Lock())
    hot.subscribe(Header, name, lambda m: None, 10)
    try:
        hot.start()
        yield driven.driver
    finally:
        sys.setswitchinterval(interval)
        os.sched_setaffinity(me, mine)  # the test runner's thread gets its cores back
        driven.driver.stop()
        hot.stop()
        node.destroy_node()
        rclpy.try_shutdown(context=driven)


def test_a_real_time_driver_shares_its_core_with_the_executor_thread(domain: int) -> None:
    """Composed under SCHED_FIFO, the driver and the thread that created the DrivenContext (the
    host's executor thread) are pinned to one core, the last the process may use, so the
    executor runs only while the driver waits, and the GIL switch interval is shortened to
    SHARED_CORE_GIL_SWITCH_S; without a thread to share with (lockstep) the driver keeps every
    core and the hot loop's interval. SCHED_FIFO refused: said in ``rt_warning``, nothing
    pinned."""
    if len(os.sched_getaffinity(0)) < 2:
        pytest.skip("one core: nothing to share")
    me = threading.get_native_id()
    mine = os.sched_getaffinity(me)
    for share in (True, False):
        sys.setswitchinterval(0.005)
        with _driver(domain, "share_probe", **({} if share else {"share_core_with": None})
                     ) as loop:
            # a helper process (the bag writer) keeps off the shared core, known before
            assert loop.spare_cpus(0) is None
            assert loop.spare_cpus(5) == (frozenset(mine) - {max(mine)} if share else None)
            loop.start(rt_priority=5)
            end = time.monotonic() + 2.0  # the thread pins itself as it starts
            while loop.core is None and loop.rt_warning is None and time.monotonic() < end:
                time.sleep(0.01)
            if loop.rt_warning is not None:
                assert "refused" in loop.rt_warning and loop.core is None
                continue
            tid = loop.native_id
            assert tid is not None
            if share:
                last = max(os.sched_getaffinity(0))
                assert loop.core == last
                assert os.sched_getaffinity(tid) == {last} == os.sched_getaffinity(me)
                assert sys.getswitchinterval() == pytest.approx(SHARED_CORE_GIL_SWITCH_S)
            else:
                assert loop.core is None and os.sched_getaffinity(tid) == mine
                assert sys.getswitchinterval() == pytest.approx(GIL_SWITCH_S)


def test_rt_cpus_choose_the_drivers_core(domain: int) -> None:
    """Composed with CPUs given (``$DCSMS_RT_CPUS``): the driver and the executor's thread
    share the last of them, not the last core of the machine; CPUs without a priority pin
    the driver alone."""
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) < 2:
        pytest.skip("one core: nothing to choose")
    first = allowed[0]
    me = threading.get_native_id()
    mine = os.sched_getaffinity(me)
    for priority in (5, 0):
        with _driver(domain, "cpus_probe", cpus=frozenset({first})) as loop:
            assert loop.spare_cpus(priority) == (frozenset(allowed) - {first} if priority
                                                 else None)
            loop.start(rt_priority=priority)
            tid = loop.native_id
            assert tid is not None and loop.core == first
            assert os.sched_getaffinity(tid) == {first}
            if priority and loop.rt_warning is None:
                assert os.sched_getaffinity(me) == {first}
            else:
                assert os.sched_getaffinity(me) == mine


def _children(parent: int, module: bytes) -> list[int]:
    """The processes ``parent`` started that run ``python -m module``."""
    found = []
    for pid in (int(p) for p in os.listdir("/proc") if p.isdigit()):
        with contextlib.suppress(OSError):  # gone meanwhile
            stat = Path(f"/proc/{pid}/stat").read_text()
            if int(stat.rsplit(")", 1)[1].split()[1]) == parent and \
                    module in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0"):
                found.append(pid)
    return found


def test_a_composed_real_time_bag_writer_keeps_off_the_drivers_core(tmp_path: Path,
                                                                   domain: int) -> None:
    """Composed in real time under SCHED_FIFO, the bag writer process (every thread of it)
    runs on the CPUs besides the core the driver shares with the executor's thread: woken
    there by a flush it preempted the executor's thread holding the GIL the driver waited
    for (docs/performance.md, "The bag writer off the driver's core")."""
    allowed = os.sched_getaffinity(0)
    if len(allowed) < 2:
        pytest.skip("one core: nothing to keep off")
    cmd = [sys.executable, "-m", "dcsms_ros.cli", "up", "--realtime", "--composed",
           "--rt-priority", "5", "--mode", "FBC", "--duration", "6",
           "--record", str(tmp_path / "bag"), "--log-dir", str(tmp_path / "logs")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen: dict[str, set[int]] = {}
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and proc.poll() is None and len(seen) < 2:
            for graph in _children(proc.pid, b"dcsms_ros.nodes.container"):
                with contextlib.suppress(OSError):  # it may end meanwhile
                    if os.sched_getscheduler(graph) == os.SCHED_OTHER \
                            and len(os.sched_getaffinity(graph)) == 1:  # the executor, pinned
                        seen["executor"] = os.sched_getaffinity(graph)
                    for writer in _children(graph, b"dcsms_ros.analysis.bagserve"):
                        seen["writer"] = set().union(*(
                            os.sched_getaffinity(int(t))
                            for t in os.listdir(f"/proc/{writer}/task")))
            time.sleep(0.2)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    logs = "".join(f.read_text() for f in (tmp_path / "logs").glob("*.log"))
    if "SCHED_FIFO priority 5 refused" in out + logs:
        pytest.skip("SCHED_FIFO refused here: no core is shared")
    assert set(seen) == {"writer", "executor"}, (seen, out)
    assert seen["writer"] == set(allowed) - seen["executor"], seen
