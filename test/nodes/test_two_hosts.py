"""More than one machine: two network namespaces joined by a veth pair stand for the rig's
real-time PC and the workstation. Plant and decoupling run in one, the controllers and the mode
switch in the other, discovering each other over the link (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET,
UDP only); a mode switch made on the controllers' side brings their forces to the plant.

The namespaces, the link and its private addresses exist only inside this test; where they
cannot be created (not root, no ``ip``, no netns support) the test is skipped with the reason.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml

from dcsms_ros.cli.deploy import node_argv
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.graph import define_graph

SIDE_A = ("plant_simulator", "sensor_decoupling")  # the "rig" side
SIDE_B = ("fb_stage1", "fb_stage2", "ff_stage1", "mode_switch")  # the "control PC" side
_TAG = f"{os.getpid() % 100000}"
NS = (f"dcsms13a{_TAG}", f"dcsms13b{_TAG}")
LINK = (f"d13a{_TAG}", f"d13b{_TAG}")
ADDR = ("10.213.77.1/24", "10.213.77.2/24")

PROBE = textwrap.dedent("""
    import sys, time
    import numpy as np, rclpy
    from rclpy.context import Context
    from sensor_msgs.msg import JointState
    from dcsms_ros.ros import qos
    ctx = Context(); rclpy.init(args=[], context=ctx)
    node = rclpy.create_node("two_host_probe", context=ctx)
    got = []
    node.create_subscription(JointState, "/dcsms/actuators/applied",
                             lambda m: got.append(max(abs(x) for x in m.effort)),
                             qos.stream_pub(False))
    ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    start = time.monotonic() + 60.0  # discovery across the link, the plant's handshake
    while not got and time.monotonic() < start:
        ex.spin_once(timeout_sec=0.05)
    got.clear()
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    print(len(got), max(got) if got else 0.0)
""")


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=30)


@pytest.fixture
def two_hosts() -> Iterator[tuple[str, str]]:
    """Two network namespaces with a veth link, private addresses and a multicast route."""
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("two network namespaces need root and iproute2 (`ip`)")
    try:
        for ns in NS:
            _ip("netns", "add", ns)
        _ip("link", "add", LINK[0], "type", "veth", "peer", "name", LINK[1])
        for ns, link, addr in zip(NS, LINK, ADDR, strict=True):
            _ip("link", "set", link, "netns", ns)
            _ip("-n", ns, "addr", "add", addr, "dev", link)
            _ip("-n", ns, "link", "set", "lo", "up")
            _ip("-n", ns, "link", "set", link, "up")
            _ip("-n", ns, "route", "add", "224.0.0.0/4", "dev", link)  # DDS discovery
    except (subprocess.CalledProcessError, OSError) as exc:
        for ns in NS:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, check=False)
        reason = exc.stderr.strip() if isinstance(exc, subprocess.CalledProcessError) else exc
        pytest.skip(f"cannot create network namespaces here: {reason}")
    try:
        yield NS
    finally:
        for ns in NS:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, check=False)


def test_controllers_on_another_host_drive_the_plant(two_hosts: tuple[str, str], domain: int,
                                                     cfg: SystemConfig, tmp_path: Path) -> None:
    """Real time across the link: before the switch the plant applies no force (Passive);
    `dcsms mode DFBC` run on the controllers' side switches, and the applied forces measured
    on the plant's side become non-zero."""
    spec = define_graph(cfg, schedule="realtime")
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(spec.params_document(), sort_keys=False))
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET", ROS_DOMAIN_ID=str(domain),
               FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1")

    def run_in(ns: str, argv: list[str]) -> list[str]:
        return ["ip", "netns", "exec", ns, *argv]

    procs = []
    try:
        for ns, names in zip(two_hosts, (SIDE_A, SIDE_B), strict=True):
            for name in names:
                log = (tmp_path / f"{name}.log").open("w")
                procs.append(subprocess.Popen(run_in(ns, node_argv(spec, name, params)),
                                              stdout=log, stderr=subprocess.STDOUT, env=env))
        before = subprocess.run(run_in(two_hosts[0], [sys.executable, "-c", PROBE, "2"]),
                                capture_output=True, text=True, env=env, timeout=120,
                                check=True).stdout.split()
        switch = subprocess.run(run_in(two_hosts[1], [sys.executable, "-m", "dcsms_ros.cli",
                                                      "mode", "DFBC", "--timeout", "90"]),
                                capture_output=True, text=True, env=env, timeout=180,
                                check=False)
        after = subprocess.run(run_in(two_hosts[0], [sys.executable, "-c", PROBE, "4"]),
                               capture_output=True, text=True, env=env, timeout=120,
                               check=True).stdout.split()
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()
    logs = "\n".join(p.read_text() for p in tmp_path.glob("*.log"))
    assert switch.returncode == 0, switch.stdout + switch.stderr + logs[-3000:]
    assert "mode DFBC" in switch.stdout
    n0, f0 = int(before[0]), float(before[1])
    n1, f1 = int(after[0]), float(after[1])
    print(f"\ntwo hosts: {n0} applied samples before the switch (max {f0:.3g} N), {n1} after "
          f"(max {f1:.3g} N)")
    assert n0 > 100 and f0 == 0.0, (before, logs[-2000:])
    assert n1 > 100 and f1 > 1e-4, (after, logs[-2000:])
    assert "Traceback" not in logs
