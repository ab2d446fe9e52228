"""An observer process receives over UDP loopback, at its full depth (ros/transport.py).

A reader process with :func:`observe_over_udp` and one without it, over real DDS: the thread
that delivers the samples (Fast DDS names them ``dds.shm.<port>`` and ``dds.udp.<port>``) is
told apart by its CPU time, and the keep-last depth that holds is counted.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest

from dcsms_ros.ros.transport import OBSERVER_PROFILE, PROFILES_VARS, observe_over_udp
from dcsms_ros.rosenv import DISCOVERY_RANGE_VAR

rclpy = pytest.importorskip("rclpy")
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

TOPIC = "/dcsms_test/observed"
SENT = 3000
DEPTH = 2000  # above Fast DDS's default max_samples_per_instance (400), which it warns about

# A reader that does not take until the writer is done: its history keeps the newest DEPTH.
# It prints which DDS threads worked.
READER = f"""
import json, os, sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from dcsms_ros.ros.transport import observe_over_udp
observed = observe_over_udp() if sys.argv[1] == "observer" else False
rclpy.init()
node = rclpy.create_node("transport_reader")
sub = node.create_subscription(String, "{TOPIC}", lambda m: None,
                               QoSProfile(depth={DEPTH}, reliability=ReliabilityPolicy.RELIABLE))

def cpu():
    out = {{}}
    for t in os.listdir("/proc/self/task"):
        name = open(f"/proc/self/task/{{t}}/comm").read().strip()
        kind = name.split(".")[1] if name.startswith("dds.") else None
        if kind in ("shm", "udp"):
            ns = int(open(f"/proc/self/task/{{t}}/schedstat").read().split()[0])
            out[kind] = out.get(kind, 0) + ns
    return out

print("ready", flush=True)
before = cpu()
sys.stdin.readline()  # the writer is done
after = cpu()
kept = 0
while sub.handle.take_message(sub.msg_type, sub.raw) is not None:
    kept += 1
print(json.dumps({{"observed": observed, "kept": kept,
                   "shm_ns": after.get("shm", 0) - before.get("shm", 0),
                   "udp_ns": after.get("udp", 0) - before.get("udp", 0)}}), flush=True)
node.destroy_node()
rclpy.try_shutdown()
"""


@pytest.mark.parametrize("env", [{}, {PROFILES_VARS[1]: "/a/profile.xml"},
                                 {DISCOVERY_RANGE_VAR: "SUBNET"}])
def test_observe_over_udp_yields_to_the_users_choice(env: dict[str, str]) -> None:
    e = dict(env)
    assert observe_over_udp(e) is (not env)
    if not env:
        assert e[PROFILES_VARS[1]] == str(OBSERVER_PROFILE) and OBSERVER_PROFILE.is_file()
    else:
        assert e == env


@pytest.mark.slow
@pytest.mark.parametrize("arm", ["observer", "default"])
def test_observer_receives_over_udp_and_keeps_its_depth(arm: str, domain: int) -> None:
    env = {k: v for k, v in os.environ.items() if k not in PROFILES_VARS}
    proc = subprocess.Popen([sys.executable, "-c", READER, arm], env=env, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    try:
        node = Node("transport_writer", context=ctx)
        pub = node.create_publisher(String, TOPIC,
                                    QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        assert proc.stdout is not None and proc.stdin is not None
        assert proc.stdout.readline().strip() == "ready", proc.communicate()
        end = time.monotonic() + 30.0
        while pub.get_subscription_count() < 1:
            assert time.monotonic() < end, "the reader did not match within 30 s"
            time.sleep(0.05)
        payload = "x" * 200
        for i in range(SENT):
            pub.publish(String(data=f"{i} {payload}"))
            time.sleep(0.0005)
        time.sleep(1.0)  # let the reliable tail arrive
        out, err = proc.communicate(input="done\n", timeout=30)
    finally:
        rclpy.try_shutdown(context=ctx)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    res = json.loads(out.strip().splitlines()[-1])
    assert res["observed"] is (arm == "observer")
    assert res["kept"] == DEPTH  # the profile leaves the reader's history as it was
    if arm == "observer":  # every sample through the UDP listener, none through shared memory
        assert res["udp_ns"] > 10 * res["shm_ns"], res
    else:
        assert res["shm_ns"] > 10 * res["udp_ns"], res
