"""The stability guard on a running graph, through real rclpy clients: a switch into a mode the
model calls unstable is refused with the pole; a tuning change that makes the active mode
unstable is rejected on the controller and on mode_switch; a harmless one goes through and
reaches ``config``."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger

from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.params_file import parse_params_text
from dcsms_ros.ros import qos

REPO = Path(__file__).resolve().parents[2]
UNSTABLE = REPO / "test" / "fixtures" / "tem_unstable.yaml"
DCSMS = [sys.executable, "-m", "dcsms_ros.cli"]


class _Graph:
    """`dcsms up --lockstep --composed` in the background, a client node in the test."""

    def __init__(self, ctx: Any, tmp: Path, *args: str) -> None:
        self.out = tmp / "up.log"
        self.proc = subprocess.Popen([*DCSMS, "up", "--lockstep", "--composed", "--log-dir",
                                      str(tmp / "logs"), *args], stdout=self.out.open("w"),
                                     stderr=subprocess.STDOUT)
        self.node = rclpy.create_node("guard_probe", context=ctx)
        self.ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.config: list[str] = []
        self.node.create_subscription(String, topics.CONFIG, lambda m: self.config.append(
            m.data), qos.latched())

    def call(self, srv: Any, name: str, req: Any, timeout: float = 120.0) -> Any:
        cli = self.node.create_client(srv, name)
        end = time.monotonic() + timeout
        while not cli.service_is_ready():
            assert time.monotonic() < end and self.proc.poll() is None, \
                f"{name} not available: {self.out.read_text()[-2000:]}"
            self.ex.spin_once(timeout_sec=0.1)
        fut = cli.call_async(req)
        while not fut.done():
            assert time.monotonic() < end, f"{name}: no answer"
            self.ex.spin_once(timeout_sec=0.05)
        return fut.result()

    def set_param(self, node: str, name: str, value: Any) -> Any:
        req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
        return self.call(SetParameters, topics.DEFAULT.set_parameters(node), req).results[0]

    def close(self) -> str:
        self.proc.send_signal(signal.SIGINT)
        self.proc.wait(60)
        self.ex.shutdown()
        self.node.destroy_node()
        return self.out.read_text()


def test_switch_into_an_unstable_mode_is_refused(ctx: Any, tmp_path: Path) -> None:
    """tem_unstable.yaml: `ros2 service call /dcsms/set_mode/dfbc` answers success=false with
    the pole; FBC (stable) switches; the start-up check printed the failing modes."""
    g = _Graph(ctx, tmp_path, "--config", str(UNSTABLE))
    try:
        bad = g.call(Trigger, topics.set_mode_service("dfbc"), Trigger.Request())
        good = g.call(Trigger, topics.set_mode_service("fbc"), Trigger.Request())
    finally:
        log = g.close()
    assert not bad.success, bad.message
    assert "DFBC is unstable" in bad.message and "pole at" in bad.message, bad.message
    assert good.success, good.message
    assert "model check: DFBC: unstable: pole" in log and "model check: DFBC+FFC" in log, log


def test_unstable_tuning_is_rejected_where_it_is_made(ctx: Any, cfg: SystemConfig,
                                                    tmp_path: Path) -> None:
    """table1 in DFBC: the stage-2 gain x50 is rejected on fb_stage2 and on mode_switch with
    the reason; x1.2 is accepted, and mode_switch republishes the configuration with it."""
    g = _Graph(ctx, tmp_path, "--mode", "dfbc")
    name = "feedback.stage2.gain"
    gain = list(cfg.params[name])
    try:
        assert g.call(Trigger, topics.set_mode_service("dfbc"), Trigger.Request()).success
        on_fb = g.set_param("fb_stage2", name, [50.0 * x for x in gain])
        on_ms = g.set_param("mode_switch", name, [50.0 * x for x in gain])
        ok = g.set_param("fb_stage2", name, [1.2 * x for x in gain])
        end = time.monotonic() + 30.0
        while time.monotonic() < end and not (g.config and parse_params_text(
                g.config[-1], "config")[name] == [1.2 * x for x in gain]):
            g.ex.spin_once(timeout_sec=0.1)
        last = parse_params_text(g.config[-1], "config")[name] if g.config else None
    finally:
        g.close()
    for res in (on_fb, on_ms):
        assert not res.successful and "DFBC is unstable" in res.reason, res.reason
    assert ok.successful, ok.reason
    assert last == [1.2 * x for x in gain], last


def test_mode_switch_refuses_an_unstable_initial_mode(domain) -> None:
    """`ros2 run dcsms_ros mode_switch --ros-args -p initial_mode:=DFBC` on the unstable
    fixture: one line naming the pole, exit 2; with allow_unstable:=true it runs DFBC."""
    node = [sys.executable, "-m", "dcsms_ros.nodes.mode_switch", "--ros-args", "--params-file",
            str(UNSTABLE), "-p", "initial_mode:=DFBC"]
    refused = subprocess.run(node, capture_output=True, text=True, timeout=60, check=False)
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert refused.stderr.count("\n") == 1 and refused.stderr.startswith(
        "dcsms: error: node mode_switch: initial_mode: DFBC is unstable"), refused.stderr
    assert "+0.0576 +0.4249j Hz" in refused.stderr
    allowed = subprocess.Popen([*node, "-p", "allow_unstable:=true"], stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(4.0)  # started, judged and running (it exits at once when it refuses)
        assert allowed.poll() is None
    finally:
        allowed.send_signal(signal.SIGINT)
        out = allowed.communicate(timeout=30)[0]
    assert allowed.returncode == 0, out
    assert "allowed (allow_unstable)" in out and "mode DFBC;" in out, out


def test_real_time_mode_switch_refuses_an_initial_mode_late_forces_destabilise(domain) -> None:
    """In real time a force is applied up to control.input_timeout_s late: with 20 ms table1's
    DFBC (16.5 ms with both loops late) is refused at start, one line, exit 2; in lockstep
    (no late force) the same parameters start."""
    node = [sys.executable, "-m", "dcsms_ros.nodes.mode_switch", "--ros-args", "--params-file",
            str(REPO / "config" / "table1.yaml"), "-p", "initial_mode:=DFBC", "-p",
            "control.input_timeout_s:=0.02"]
    refused = subprocess.run(node, capture_output=True, text=True, timeout=60, check=False)
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert refused.stderr.count("\n") == 1 and refused.stderr.startswith(
        "dcsms: error: node mode_switch: initial_mode: DFBC goes unstable with forces 20 ms "
        "late"), refused.stderr
    lockstep = subprocess.Popen([*node, "-p", "schedule:=lockstep"], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(4.0)  # started and running (it exits at once when it refuses)
        assert lockstep.poll() is None
    finally:
        lockstep.send_signal(signal.SIGINT)
        out = lockstep.communicate(timeout=30)[0]
    assert lockstep.returncode == 0, out
