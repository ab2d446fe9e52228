"""The package's processes meet over UDP loopback, never shared memory (ros/transport.py).

A writer process and a reader process, both started through :func:`ros_context` as every
process of the package is, over real DDS: what each maps of Fast DDS's shared-memory ports
(``fastrtps_port*``), which DDS thread delivers the reader's samples (Fast DDS names them
``dds.shm.<port>`` and ``dds.udp.<port>``; told apart by their CPU time) and the keep-last depth
that holds. A process with a profile file of the user's own (Fast DDS's defaults, as a tool
outside the package has) shows the shared-memory path, with its port health check, that the
package avoids.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree

import pytest

from dcsms_ros.ros.transport import (
    PROFILE,
    PROFILES_VARS,
    loopback_over_udp,
    widen_udp_receive_buffers,
)
from dcsms_ros.rosenv import DISCOVERY_RANGE_VAR

pytest.importorskip("rclpy")

TOPIC = "/dcsms_test/loopback"
SENT = 3000
DEPTH = 2000  # above Fast DDS's default max_samples_per_instance (400), which it warns about

COMMON = """
import json, os, re, sys, time
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from dcsms_ros.ros.context import ros_context

def shm_ports():
    return sorted(set(re.findall(r"fastrtps_(port\\d+)", open("/proc/self/maps").read())))

def thread_cpu():
    out = {}
    for t in os.listdir("/proc/self/task"):
        name = open(f"/proc/self/task/{t}/comm").read().strip()
        kind = name.split(".")[1] if name.startswith("dds.") else None
        if kind in ("shm", "udp"):
            ns = int(open(f"/proc/self/task/{t}/schedstat").read().split()[0])
            out[kind] = out.get(kind, 0) + ns
    return out

QOS = QoSProfile(depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE)

def wait_matched(pub):
    end = time.monotonic() + 30.0
    while pub.get_subscription_count() < 1:
        assert time.monotonic() < end, "the reader did not match within 30 s"
        time.sleep(0.05)
""".replace("DEPTH", str(DEPTH))

# A reader that does not take until the writer is done: its history keeps the newest DEPTH.
READER = COMMON + f"""
with ros_context([]) as ros:
    node = Node("loopback_reader", context=ros.context)
    sub = node.create_subscription(String, "{TOPIC}", lambda m: None, QOS)
    print("ready", flush=True)
    before = thread_cpu()
    sys.stdin.readline()  # the writer is done
    after = thread_cpu()
    kept = 0
    while sub.handle.take_message(sub.msg_type, sub.raw) is not None:
        kept += 1
    print(json.dumps({{"kept": kept, "ports": shm_ports(),
                       "shm_ns": after.get("shm", 0) - before.get("shm", 0),
                       "udp_ns": after.get("udp", 0) - before.get("udp", 0)}}), flush=True)
    node.destroy_node()
"""

WRITER = COMMON + f"""
with ros_context([]) as ros:
    node = Node("loopback_writer", context=ros.context)
    pub = node.create_publisher(String, "{TOPIC}", QOS)
    wait_matched(pub)
    payload = "x" * 200
    for i in range({SENT}):
        pub.publish(String(data=f"{{i}} {{payload}}"))
        time.sleep(0.0005)
    time.sleep(1.0)  # let the reliable tail arrive
    print(json.dumps({{"ports": shm_ports()}}), flush=True)
    node.destroy_node()
"""


@pytest.mark.parametrize("env", [{}, {PROFILES_VARS[1]: "/a/profile.xml"},
                                 {PROFILES_VARS[0]: "/a/profile.xml"},
                                 {DISCOVERY_RANGE_VAR: "SUBNET"}])
def test_loopback_over_udp_yields_to_the_users_choice_and_cleans_up(env: dict[str, str]) -> None:
    e = dict(env)
    with loopback_over_udp(e) as applied:
        assert applied is (not env)
        if not env:
            assert e[PROFILES_VARS[1]] == str(PROFILE) and PROFILE.is_file()
        else:
            assert e == env
    assert e == env  # a child started later (another host's range) chooses for itself


def test_a_recorder_widens_its_udp_receive_buffers() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp, \
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp:
        before = tcp.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        sizes = widen_udp_receive_buffers(1 << 20)
        got = udp.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        assert got >= 1 << 20 and got in sizes  # Linux reports twice what was asked
        assert tcp.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) == before
    assert sizes and all(s >= 1 << 20 for s in sizes)


def test_the_profile_announces_often_while_a_graph_starts() -> None:
    """A participant keeps announcing itself for longer than a node process takes to start
    (the supervisor's participant exists ~1-2.5 s before its children's), then every second:
    with Fast DDS's 5 x 100 ms and 3 s, `dcsms up` waited for a 3 s announcement (1.0 or 3.6 s
    composed, 3.4-3.8 s per process; 0.9-1.1 and 2.2-2.6 s with these, docs/performance.md)."""
    ns = {"p": "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"}
    disc = ElementTree.parse(PROFILE).find(
        "p:participant/p:rtps/p:builtin/p:discovery_config", ns)
    assert disc is not None

    def seconds(e: ElementTree.Element | None) -> float:
        assert e is not None
        return float(e.findtext("p:sec", "0", ns)) + float(e.findtext("p:nanosec", "0", ns)) / 1e9

    count = int(disc.findtext("p:initialAnnouncements/p:count", "0", ns))
    period = seconds(disc.find("p:initialAnnouncements/p:period", ns))
    assert count * period >= 3.0 and period <= 0.2
    assert seconds(disc.find("p:leaseAnnouncement", ns)) <= 1.0


OWN_PROFILE = ('<?xml version="1.0" encoding="UTF-8" ?>\n'
               '<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">\n'
               '  <participant profile_name="users_own"><rtps/></participant>\n'
               '</profiles>\n')


@pytest.mark.slow
@pytest.mark.parametrize(("writer_role", "reader_role"), [
    ("package", "package"),  # e.g. the plant and the decoupling, or the recorder
    ("package", "outside"),  # `ros2 topic echo` with Fast DDS's defaults
    ("outside", "outside"),
])
def test_the_package_never_uses_shared_memory(writer_role: str, reader_role: str, domain: int,
                                              tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in PROFILES_VARS}
    own = tmp_path / "own.xml"  # a profile file of the user's own that keeps the defaults
    own.write_text(OWN_PROFILE)
    envs = {"package": env, "outside": {**env, PROFILES_VARS[1]: str(own)}}
    reader = subprocess.Popen([sys.executable, "-c", READER], env=envs[reader_role], text=True,
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE)
    try:
        assert reader.stdout is not None
        assert reader.stdout.readline().strip() == "ready", reader.communicate()
        writer = subprocess.run([sys.executable, "-c", WRITER], env=envs[writer_role],
                                text=True, capture_output=True, timeout=120, check=False)
        assert writer.returncode == 0, writer.stderr
        out, err = reader.communicate(input="done\n", timeout=30)
    finally:
        if reader.poll() is None:
            reader.kill()
    assert reader.returncode == 0, err
    wrote = json.loads(writer.stdout.strip().splitlines()[-1])
    read = json.loads(out.strip().splitlines()[-1])
    assert read["kept"] == DEPTH  # the profile leaves the reader's history as it was
    if reader_role == "package":  # no shared-memory port on either side; all through UDP
        assert wrote["ports"] == [] and read["ports"] == [], (wrote, read)
        assert read["udp_ns"] > 10 * read["shm_ns"], read
    else:  # the writer opened the reader's port: the path with the 333 ms health check
        assert read["ports"] and set(read["ports"]) <= set(wrote["ports"]), (wrote, read)
        if writer_role == "outside":
            assert read["shm_ns"] > 10 * read["udp_ns"], read



ACKED = COMMON + f"""
from rclpy.duration import Duration
with ros_context([]) as ros:
    node = Node("ack_probe", context=ros.context)
    pub = node.create_publisher(String, "{TOPIC}", QOS)
    wait_matched(pub)
    waits = []
    for i in range(5):
        pub.publish(String(data=str(i)))
        t0 = time.monotonic()
        assert pub.wait_for_all_acked(Duration(seconds=10.0))
        waits.append(time.monotonic() - t0)
    print(json.dumps(waits), flush=True)
    node.destroy_node()
"""


@pytest.mark.slow
def test_a_reader_acknowledges_within_a_heartbeat(domain: int, tmp_path: Path) -> None:
    """A process's exit waits until the readers of its last messages (the supervisor's, a
    recorder's) acknowledged them, and a reader acknowledges when a heartbeat asks. The
    profile's 100 ms heartbeat keeps that wait short; with Fast DDS's 3 s `dcsms up --composed
    --lockstep --duration 30` waited up to 3.1 s at its exit (docs/performance.md)."""
    env = {k: v for k, v in os.environ.items() if k not in PROFILES_VARS}
    own = tmp_path / "own.xml"  # Fast DDS's defaults
    own.write_text(OWN_PROFILE)
    waits = {}
    for role, e in {"package": env, "outside": {**env, PROFILES_VARS[1]: str(own)}}.items():
        reader = subprocess.Popen([sys.executable, "-c", READER], env=e, text=True,
                                  stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE)
        try:
            assert reader.stdout is not None
            assert reader.stdout.readline().strip() == "ready", reader.communicate()
            run = subprocess.run([sys.executable, "-c", ACKED], env=e, text=True,
                                 capture_output=True, timeout=120, check=False)
            reader.communicate(input="done\n", timeout=30)
        finally:
            if reader.poll() is None:
                reader.kill()
        assert run.returncode == 0, run.stderr
        waits[role] = json.loads(run.stdout.strip().splitlines()[-1])
    print(f"acknowledgement waits, s: {waits}")
    assert max(waits["package"]) < 0.5, waits
    assert max(waits["outside"]) > 0.5, waits  # the 3 s default, shown on the same machine
