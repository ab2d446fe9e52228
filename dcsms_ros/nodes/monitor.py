"""The supervising side of ``dcsms up``: wait for the graph, show status, watch the processes.

A small node in the ``up`` process subscribes to ``/dcsms/mode`` and ``/dcsms/diagnostics``
only (1 Hz reports, not the 2 kHz streams) and checks the graph's connections.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String
from std_srvs.srv import Trigger

from dcsms_ros.core import topics
from dcsms_ros.core.modes import Mode, controller_ids
from dcsms_ros.nodes import qos

#: Seconds between status lines on a terminal, and when the output is a file or a pipe.
STATUS_PERIOD_TTY = 0.5
STATUS_PERIOD_PIPE = 5.0


class GraphMonitor:
    """Connection check and status line of a running graph with ``n`` stages."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.ctx = Context()
        rclpy.init(args=[], context=self.ctx, signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(f"dcsms_up_{os.getpid()}", context=self.ctx)
        self.mode: str | None = None
        self.diag: dict[str, dict[str, str]] = {}
        self.messages: dict[str, str] = {}
        self.node.create_subscription(String, topics.MODE, self._on_mode, qos.latched())
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diag,
                                      qos.status())
        self.set_mode = self.node.create_client(Trigger,
                                                topics.set_mode_service(Mode.PASSIVE.value))
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.tty = sys.stdout.isatty()

    def _on_mode(self, msg: String) -> None:
        self.mode = msg.data

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            self.diag[st.name] = {kv.key: kv.value for kv in st.values}
            self.messages[st.name] = st.message

    def missing(self) -> list[str]:
        """What is not connected yet (empty when the graph is up)."""
        node = self.node
        out = [c for c in controller_ids(self.n)
               if node.count_publishers(topics.force_topic(c)) == 0]
        if node.count_subscribers(topics.SENSORS_RAW) == 0:
            out.append("sensor_decoupling")
        if node.count_publishers(topics.SENSORS_RAW) == 0:
            out.append("plant_simulator")
        if self.mode is None or not self.set_mode.service_is_ready():
            out.append("mode_switch")
        return out

    def status_line(self) -> str:
        """``t=… s  rate=… Hz  mode=…  faults=…``."""
        p = self.diag.get("plant_simulator", {})
        ms = self.diag.get("mode_switch", {})
        faults = sum(int(p.get(k, "0")) for k in ("lockstep_timeouts", "stale_events",
                                                   "nonfinite_inputs", "overruns"))
        trip = "  TRIPPED" if ms.get("tripped") == "True" else ""
        degraded = self.messages.get("plant_simulator", "")
        extra = f"  [{degraded}]" if degraded.startswith("degraded") else ""
        return (f"t={float(p.get('sim_time_s', 0.0)):9.3f} s  "
                f"rate={float(p.get('achieved_rate_hz', 0.0)):7.1f} Hz  "
                f"mode={self.mode or '?'}  faults={faults}  "
                f"saturations={p.get('saturations', '0')}{trip}{extra}")

    def supervise(self, kids: Sequence[Any], stop: Callable[[], bool], connect_timeout: float,
                  expect_finish: bool) -> int:
        """Wait for the graph, then print status until ``stop()`` or the plant finishes.

        Returns 0 after a stop request or a finished run, 1 if a node died or the graph did not
        connect within ``connect_timeout`` seconds.
        """
        t0 = time.monotonic()
        connected = False
        last = 0.0
        period = STATUS_PERIOD_TTY if self.tty else STATUS_PERIOD_PIPE
        while not stop():
            self.executor.spin_once(timeout_sec=0.1)
            for kid in kids:
                code = kid.proc.poll() if kid.proc is not None else None
                if code is None:
                    continue
                if kid.name == "plant_simulator" and code == 0 and expect_finish:
                    for _ in range(20):  # its last report may still be in flight
                        if self.diag.get("plant_simulator", {}).get("finished") == "True":
                            break
                        self.executor.spin_once(timeout_sec=0.05)
                    if self.diag.get("plant_simulator", {}).get("finished") == "True":
                        self._print(self.status_line(), final=True)
                        print("dcsms up: run finished", flush=True)
                        return 0
                self._print("", final=True)
                print(f"dcsms up: error: node {kid.name} exited with status {code}"
                      + (f"; last log lines ({kid.log}):\n{_tail(kid.log)}" if kid.log else ""),
                      file=sys.stderr, flush=True)
                return 1
            now = time.monotonic()
            if not connected:
                missing = self.missing()
                if not missing:
                    connected = True
                    print(f"dcsms up: graph connected in {now - t0:.1f} s", flush=True)
                elif now - t0 > connect_timeout:
                    print(f"dcsms up: error: graph not connected after {connect_timeout:g} s; "
                          f"missing: {', '.join(missing)}", file=sys.stderr, flush=True)
                    return 1
                continue
            if now - last >= period:
                last = now
                self._print(self.status_line())
        self._print(self.status_line(), final=True)
        return 0

    def _print(self, line: str, final: bool = False) -> None:
        if self.tty:
            sys.stdout.write("\r\x1b[K" + line + ("\n" if final and line else ""))
        elif line:
            sys.stdout.write(line + "\n")
        sys.stdout.flush()

    def close(self) -> None:
        """Destroy the node and shut its context down."""
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def _tail(path: Any, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace").splitlines()[-lines:]
    except OSError:
        return ""
    return "\n".join("    " + t for t in text)
