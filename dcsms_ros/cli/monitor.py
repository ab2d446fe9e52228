"""The supervising side of ``dcsms up``: wait for the graph, show status, drive a mode
schedule, watch the processes.

A small node in the ``up`` process subscribes to the graph's ``mode`` and to ``/diagnostics``
(1 Hz reports, not the 2 kHz streams, only shown), checks the graph's connections and, given a
mode schedule, switches through the real ``set_mode/<mode>`` services. What it decides on
travels on typed topics: ``plant/held`` and ``plant/finished``. In lockstep a switch lands on a
defined sample: the plant holds before the sample of the next switch (``hold_at_s``), says so
on ``plant/held``, the switch is made, and the hold moves on to the following switch, so the
run is the batch engine's bit for bit. In real time the switch is made when ``/clock`` passes
its time.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool, Int64, String
from std_srvs.srv import Trigger

from dcsms_ros.core import topics
from dcsms_ros.core.modes import Mode, controller_ids
from dcsms_ros.graph import GraphSpec
from dcsms_ros.ros import qos
from dcsms_ros.ros.connectivity import End, control_path, missing_ends
from dcsms_ros.ros.context import ros_context, spin_until

#: Seconds between status lines on a terminal, and when the output is a file or a pipe.
STATUS_PERIOD_TTY = 0.5
STATUS_PERIOD_PIPE = 5.0
PLANT = topics.PLANT_ID


class GraphMonitor:
    """Connection check, status line and mode schedule of a running graph.

    Parameters
    ----------
    spec : GraphSpec
        The graph (namespace, schedule, stages).
    context : Context
        An initialised rclpy context (:func:`monitoring` makes one).
    events : sequence of (time_s, Mode)
        Mode switches at simulated times, sorted.
    rate_hz : float
        Sample rate (lockstep switches land on sample ``round(t * rate)``).
    """

    def __init__(self, spec: GraphSpec, context: Context,
                 events: Sequence[tuple[float, Mode]] = (), rate_hz: float = 2000.0) -> None:
        self.spec = spec
        self.n = spec.num_stages
        self.names = spec.names
        self.ctx = context
        self.node = Node(f"dcsms_up_{os.getpid()}", context=self.ctx)
        self.mode: str | None = None
        self.diag: dict[str, dict[str, str]] = {}
        self.messages: dict[str, str] = {}
        self.sim_time = -1.0
        #: the sample the plant holds before (lockstep), -1: none yet
        self.held_at = -1
        self.finished = False
        nd = self.node
        nd.create_subscription(String, self.names.mode, self._on_mode, qos.latched())
        nd.create_subscription(Bool, self.names.plant_finished, self._on_finished, qos.latched())
        nd.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diag,
                               qos.status())
        self.set_mode = {m: nd.create_client(Trigger, self.names.set_mode(m.value))
                         for m in Mode}
        self.events = list(events)
        self.lockstep = spec.schedule == "lockstep"
        self.rate = rate_hz
        self.switches: list[tuple[float, str, bool, str]] = []  # (t, mode, success, message)
        self._next = 0
        self._pending: Any = None
        self._releasing: Any = None
        if self.events:
            self.set_params = nd.create_client(SetParameters, self.names.set_parameters(PLANT))
            if not self.lockstep:
                nd.create_subscription(Clock, topics.CLOCK, self._on_clock,
                                       qos_profile_sensor_data)
            else:
                nd.create_subscription(Int64, self.names.plant_held, self._on_held,
                                       qos.latched())
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(nd)
        self.tty = sys.stdout.isatty()

    def _on_mode(self, msg: String) -> None:
        self.mode = msg.data

    def _on_held(self, msg: Int64) -> None:
        self.held_at = msg.data

    def _on_finished(self, msg: Bool) -> None:
        self.finished = self.finished or msg.data

    def _on_clock(self, msg: Clock) -> None:
        self.sim_time = msg.clock.sec + msg.clock.nanosec * 1e-9

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for st in msg.status:
            name = self.names.local_status(st.name)
            if name is None:
                continue  # another graph on the same network
            values = {kv.key: kv.value for kv in st.values}
            old = self.diag.get(name, {})
            if name == PLANT and values.get("finished") == "True" and \
                    values.get("sample") == old.get("sample") and "achieved_rate_hz" in old:
                # the plant's final report follows its last one at once: a window without a
                # sample says nothing about the rate (a stall shows 0 before it finishes)
                values["achieved_rate_hz"] = old["achieved_rate_hz"]
            self.diag[name] = values
            self.messages[name] = st.message

    def missing(self) -> list[str]:
        """What is not connected yet (empty when the graph is up)."""
        nm = self.names
        out = missing_ends(self.node, [*control_path(nm, controller_ids(self.n)),
                                       End(nm.sensors_raw, True, PLANT)])
        if self.mode is None or not self.set_mode[Mode.PASSIVE].service_is_ready():
            out.append("mode_switch")
        return out

    # -- schedule ----------------------------------------------------------------------------
    def _sample(self, i: int) -> int:
        return int(round(self.events[i][0] * self.rate))

    def drive(self) -> None:
        """Make the next scheduled switch when it is due (call often)."""
        if self._releasing is not None:
            if not self._releasing.done():
                return
            self._releasing = None
        if self._pending is not None:
            if not self._pending.done():
                return
            res = self._pending.result()
            t, m = self.events[self._next]
            ok, text = (res.success, res.message) if res is not None else (False, "no answer")
            self.switches.append((t, m.label, ok, text))
            if not ok:
                print(f"dcsms up: switch to {m.label} at t={t:g} s refused: {text}",
                      file=sys.stderr, flush=True)
            self._pending = None
            self._next += 1
            if self.lockstep and (self._next == len(self.events)
                                  or self._sample(self._next) != self._sample(self._next - 1)):
                # move the plant's hold to the next switch (0: none) and let it go on
                hold = self.events[self._next][0] if self._next < len(self.events) else 0.0
                req = SetParameters.Request(parameters=[
                    Parameter("hold_at_s", value=float(hold)).to_parameter_msg()])
                self._releasing = self.set_params.call_async(req)
            return
        if self._next >= len(self.events):
            return
        t, m = self.events[self._next]
        due = self.held_at == self._sample(self._next) if self.lockstep else self.sim_time >= t
        if due and self.set_mode[m].service_is_ready():
            self._pending = self.set_mode[m].call_async(Trigger.Request())

    # -- status ------------------------------------------------------------------------------
    def status_line(self) -> str:
        """``t=… s  rate=… Hz  mode=…  faults=…``."""
        p = self.diag.get(PLANT, {})
        ms = self.diag.get("mode_switch", {})
        faults = sum(int(p.get(k, "0")) for k in ("lockstep_timeouts", "stale_events",
                                                   "nonfinite_inputs", "overruns", "late_steps"))
        state = ms.get("supervisor", "off")
        # the supervisor's state when it is not simply running the user's mode
        trip = (f"  {state}" if state not in ("off", "ENGAGED") else
                "  TRIPPED" if ms.get("tripped") == "True" else "")
        degraded = self.messages.get(PLANT, "")
        extra = f"  [{degraded}]" if degraded.startswith("degraded") else ""
        if self.finished:  # the plant waits for its readers (the recorder)
            extra += "  finished; delivering the last samples"
        return (f"t={float(p.get('sim_time_s', 0.0)):9.3f} s  "
                f"rate={float(p.get('achieved_rate_hz', 0.0)):7.1f} Hz  "
                f"mode={self.mode or '?'}  faults={faults}  "
                f"saturations={p.get('saturations', '0')}{trip}{extra}")

    def supervise(self, kids: Sequence[Any], stop: Callable[[], bool], connect_timeout: float,
                  expect_finish: bool) -> int:
        """Wait for the graph, then drive the schedule and print status until ``stop()`` or
        the plant finishes.

        Returns 0 after a stop request or a finished run, 1 if a process died or the graph
        did not connect within ``connect_timeout`` seconds.
        """
        t0 = time.monotonic()
        connected = False
        last = 0.0
        period = STATUS_PERIOD_TTY if self.tty else STATUS_PERIOD_PIPE
        plant_proc = {PLANT, "graph"}  # the plant's process: its own, or the composed one
        while not stop():
            self.executor.spin_once(timeout_sec=0.01 if self.events else 0.1)
            for kid in kids:
                code = kid.proc.poll() if kid.proc is not None else None
                if code is None:
                    continue
                # a finished run: the plant's last report may still be in flight
                if kid.name in plant_proc and code == 0 and expect_finish and spin_until(
                        self.executor, lambda: self.finished, timeout_s=1.0, poll_s=0.05):
                    self._print(self.status_line(), final=True)
                    print("dcsms up: run finished", flush=True)
                    return 0
                self._print("", final=True)
                print(f"dcsms up: error: {kid.name} exited with status {code}"
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
            if self.events:
                self.drive()
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
        """Stop the executor and destroy the node (the context is the caller's)."""
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()


@contextmanager
def monitoring(spec: GraphSpec, events: Sequence[tuple[float, Mode]] = (),
               rate_hz: float = 2000.0) -> Iterator[GraphMonitor]:
    """A :class:`GraphMonitor` on its own rclpy context for the ``with`` block; closed, and the
    context shut down, when it ends. Signals stay with the caller (``dcsms up`` holds its own
    stop flag), and the caller's command line is not read as ROS arguments."""
    with ros_context([]) as ros:
        monitor = GraphMonitor(spec, ros.context, events, rate_hz)
        try:
            yield monitor
        finally:
            monitor.close()


def _tail(path: Any, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace").splitlines()[-lines:]
    except OSError:
        return ""
    return "\n".join("    " + t for t in text)
