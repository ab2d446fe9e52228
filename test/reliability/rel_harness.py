"""Helpers of the reliability tests: a node graph whose processes the test can kill, a probe
node that records the streams, and the results file docs/reliability.md's table comes from."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from dcsms_ros.cli.deploy import children
from dcsms_ros.cli.processes import Child, child_env, stop_in_turn
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import Mode
from dcsms_ros.graph import define_graph
from dcsms_ros.ros import qos

REPO = Path(__file__).resolve().parents[2]
TABLE1 = REPO / "config" / "table1.yaml"
DCSMS = [sys.executable, "-m", "dcsms_ros.cli"]
#: frame_id of the messages a test injects (the probe does not record them as outputs).
INJECTED = "injected"


def results_file() -> Path:
    """Where the tests append their figures (``DCSMS_RELIABILITY_RESULTS`` or a temp dir)."""
    env = os.environ.get("DCSMS_RELIABILITY_RESULTS")
    path = Path(env) if env else Path(tempfile.gettempdir()) / "dcsms-reliability.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def report(row: str, fault: str, result: str, figure: str, **data: Any) -> None:
    """Append one JSON line (``row`` orders docs/reliability.md's table) to :func:`results_file`."""
    line = {"row": row, "fault": fault, "result": result, "figure": figure,
            "time": time.strftime("%Y-%m-%dT%H:%M:%S"), **data}
    with results_file().open("a") as f:
        f.write(json.dumps(line) + "\n")
    print(f"\n[{row}] {fault}: {result} ({figure})")


def assert_clean(logs: str) -> None:
    """No traceback and no rclpy shutdown noise in the node logs."""
    assert "Traceback" not in logs, logs[-3000:]
    assert "never retrieved" not in logs, "an rclpy task failed silently at shutdown"


def mono_ns() -> int:
    """CLOCK_MONOTONIC in ns: the same clock in every process on this host."""
    return time.monotonic_ns()


class Jitter:
    """Scheduling delay of this machine: a thread sleeps 1 ms in a loop and records by how much
    each sleep overran. A user-space watchdog cannot act faster than the OS schedules it, so the
    fault tests allow the overrun measured around the fault on top of their bound (and report
    it: on an idle machine it is well under 1 ms)."""

    def __init__(self) -> None:
        self.samples: list[tuple[int, int]] = []
        self._run = True
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while self._run:
            t = mono_ns()
            time.sleep(0.001)
            self.samples.append((t, mono_ns() - t - 1_000_000))

    def worst(self, t0: int, t1: int) -> float:
        """Largest overrun (s) of a sleep that started in [t0, t1] (monotonic ns)."""
        return max((d for t, d in list(self.samples) if t0 <= t <= t1), default=0) / 1e9

    def close(self) -> None:
        self._run = False
        self.thread.join(2)


class Graph:
    """The ``dcsms up`` node processes, started by the test so it can signal each one."""

    def __init__(self, cfg: SystemConfig, tmp: Path, schedule: str = "realtime",
                 mode: Mode = Mode.DFBC_FFC, duration_s: float = 0.0,
                 extra: dict[str, dict[str, Any]] | None = None,
                 allow_unstable: bool = False, rt_priority: int = 0) -> None:
        self.cfg, self.mode, self.tmp = cfg, mode, tmp
        spec = define_graph(cfg, schedule=schedule, mode=mode, duration_s=duration_s,
                            allow_unstable=allow_unstable)
        for node, values in (extra or {}).items():
            spec = spec.with_params(node, **values)
        self.params = tmp / "params.yaml"
        self.params.write_text(yaml.safe_dump(spec.params_document(), sort_keys=False))
        self.kids = {k.name: k for k in children(spec, self.params, rt_priority)}
        self.env = child_env()
        for kid in self.kids.values():
            self.start(kid.name)

    def start(self, name: str, extra_args: tuple[str, ...] = ()) -> None:
        """(Re)start node ``name``; its log is appended to ``<tmp>/<name>.log``."""
        kid: Child = self.kids[name]
        kid.log = self.tmp / f"{name}.log"
        with kid.log.open("ab") as out:
            kid.proc = subprocess.Popen([*kid.argv, *extra_args], stdout=out,
                                        stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                        env={**self.env, **kid.env},
                                        start_new_session=True)

    def plant_param(self, name: str, default: Any) -> Any:
        """The plant's value of node parameter ``name`` (as set here, else its default)."""
        doc = yaml.safe_load(self.params.read_text())
        own = doc.get(f"{topics.NAMESPACE}/plant_simulator", {}).get("ros__parameters", {})
        return own.get(name, doc["/**"]["ros__parameters"].get(name, default))

    def pid(self, name: str) -> int:
        proc = self.kids[name].proc
        assert proc is not None
        return proc.pid

    def kill(self, name: str, sig: int = signal.SIGKILL) -> int:
        """Send ``sig`` to node ``name``; returns the monotonic time (ns) just before."""
        t = mono_ns()
        os.kill(self.pid(name), sig)
        if sig == signal.SIGKILL:
            self.kids[name].proc.wait(10)  # type: ignore[union-attr]
        return t

    def logs(self) -> str:
        return "\n".join(p.read_text(errors="replace") for p in self.tmp.glob("*.log"))

    def stop(self) -> dict[str, int | None]:
        """SIGINT the nodes one at a time (after SIGCONT), as ``dcsms up`` stops them; exit
        status per node.
        A node still running 10 s later is aborted, and the stacks its fault handler wrote
        are printed (pytest shows them with a failure)."""
        alive = [k for k in self.kids.values() if k.proc and k.proc.poll() is None]
        for k in alive:
            os.kill(k.proc.pid, signal.SIGCONT)  # type: ignore[union-attr]
        stop_in_turn(alive, (10.0, 1.0))
        for k in alive:
            if k.stopped_by is not signal.SIGINT and k.log is not None:
                print(f"--- {k.name} did not stop after SIGINT (exit {k.proc.returncode}); "  # type: ignore[union-attr]
                      f"the end of its log:\n{k.log.read_text(errors='replace')[-8000:]}")
        return {k.name: k.proc.returncode if k.proc else None for k in self.kids.values()}


def _deep(depth: int = 5000, reliable: bool = True) -> QoSProfile:
    """A deep reader; a per-sample stream's must be best effort (the real-time writers are: a
    reliable reader would not match them, see ros/qos.py)."""
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=ReliabilityPolicy.RELIABLE if reliable
                      else ReliabilityPolicy.BEST_EFFORT)


class Probe:
    """A node in the test process that records applied forces, commands, diagnostics, mode.

    Spun in a background thread; every list holds ``(recv_mono_ns, stamp_ns, values)``.
    """

    def __init__(self, ctx: Context, forces: tuple[str, ...] = (), applied: bool = True) -> None:
        self.node = rclpy.create_node(f"reliability_probe_{os.getpid()}", context=ctx)
        self.lock = threading.Lock()
        self.applied: list[tuple[int, int, tuple[float, ...]]] = []
        self.forces: dict[str, list[tuple[int, int, tuple[float, ...]]]] = {
            c: [] for c in forces}
        self.diag: dict[str, dict[str, str]] = {}
        self.diag_msgs: dict[str, str] = {}
        self.diag_log: list[tuple[int, str, str, dict[str, str]]] = []
        self.modes: list[tuple[int, str]] = []
        nd = self.node
        if applied:  # an observer of applied: the plant's start may wait for it
            nd.create_subscription(JointState, topics.ACTUATORS_APPLIED, self._on_applied,
                                   _deep(reliable=False))
        for c in self.forces:
            nd.create_subscription(WrenchStamped, topics.force_topic(c),
                                   lambda m, c=c: self._on_force(c, m), _deep(reliable=False))
        nd.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diag, _deep(100))
        nd.create_subscription(String, topics.MODE, self._on_mode, qos.latched())
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(nd)
        self._run = True
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while self._run:
            self.executor.spin_once(timeout_sec=0.05)

    def _on_applied(self, m: JointState) -> None:
        ns = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        with self.lock:
            self.applied.append((mono_ns(), ns, tuple(m.effort)))

    def _on_force(self, c: str, m: WrenchStamped) -> None:
        if m.header.frame_id == INJECTED:
            return  # the test's own fault injection, not the controller's output
        ns = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        f, t = m.wrench.force, m.wrench.torque
        with self.lock:
            self.forces[c].append((mono_ns(), ns, (f.x, f.y, f.z, t.x, t.y, t.z)))

    def _on_diag(self, m: DiagnosticArray) -> None:
        with self.lock:
            for st in m.status:
                name = topics.DEFAULT.local_status(st.name)
                if name is None:
                    continue  # another graph's node
                values = {kv.key: kv.value for kv in st.values}
                self.diag[name] = values
                self.diag_msgs[name] = st.message
                self.diag_log.append((mono_ns(), name, st.message, values))

    def _on_mode(self, m: String) -> None:
        with self.lock:
            self.modes.append((mono_ns(), m.data))

    def value(self, node: str, key: str, default: str = "") -> str:
        with self.lock:
            return self.diag.get(node, {}).get(key, default)

    def status_after(self, node: str, after_ns: int) -> tuple[str, dict[str, str]] | None:
        """The newest (message, values) of status ``node`` received after ``after_ns``."""
        with self.lock:
            for t, name, msg, values in reversed(self.diag_log):
                if t <= after_ns:
                    return None
                if name == node:
                    return msg, values
        return None

    def seen_after(self, node: str, after_ns: int, message: str) -> bool:
        """True if status ``node`` reported ``message`` at some point after ``after_ns``."""
        with self.lock:
            return any(t > after_ns and name == node and msg == message
                       for t, name, msg, _ in self.diag_log)

    def applied_reaches(self, k: int, rate_hz: float) -> bool:
        """True once an applied-force sample with index >= ``k`` arrived."""
        with self.lock:
            return bool(self.applied) and self.applied[-1][1] >= k * 1e9 / rate_hz

    def wait(self, cond: Callable[[], bool], timeout: float, what: str) -> None:
        """Wait for ``cond()`` (polled every 20 ms); fail with ``what`` after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < deadline, f"timed out after {timeout:g} s: {what}"
            time.sleep(0.02)

    def close(self) -> None:
        self._run = False
        self.thread.join(5)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()


def call(args: list[str], timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    """Run ``dcsms ARGS`` to completion."""
    return subprocess.run([*DCSMS, *args], capture_output=True, text=True, timeout=timeout,
                          check=False)
