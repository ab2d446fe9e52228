"""rclpy ping-pong bound: two processes echoing a geometry_msgs/TwistStamped.

The pinger publishes on ``/bench/ping``, the echo process (``python bench/pingpong.py --echo``)
republishes each message on ``/bench/pong``, and the pinger sends the next one only when the
previous came back: round trips per second is the ceiling of any lockstep graph in which one
step needs one message exchange between two processes. The pinger spins a
SingleThreadedExecutor (``--ping events``: rclpy's EventsExecutor); the echo side that one or
(``--executor events``) the EventsExecutor, each driven by a ``spin_once`` loop.
``--executor hot`` (echo) and ``ping="hot"`` serve the subscription from a minimal wait set
instead, as the dcsms nodes' hot path does (``dcsms_ros/ros/hotpath.py``).
Reliable QoS, depth 1.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import time
from typing import Any

PING, PONG = "/bench/ping", "/bench/pong"


def _executor(kind: str) -> Any:
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


def echo(executor: str) -> None:
    """Echo process: republish every ping as a pong until killed."""
    import rclpy
    from geometry_msgs.msg import TwistStamped

    rclpy.init()
    node = rclpy.create_node("bench_echo")
    pub = node.create_publisher(TwistStamped, PONG, 1)
    if executor == "hot":
        import threading

        from rclpy.qos import QoSProfile

        from dcsms_ros.ros.hotpath import HotPath

        hot = HotPath(node, threading.Lock())
        hot.subscribe(TwistStamped, PING, pub.publish, QoSProfile(depth=1))
        hot.start()
        executor = "single"  # parameter services etc. stay on the default executor
        import atexit

        atexit.register(hot.stop)
    else:
        node.create_subscription(TwistStamped, PING, pub.publish, 1)
    ex = _executor(executor)
    ex.add_node(node)
    print("ready", flush=True)
    with contextlib.suppress(KeyboardInterrupt, Exception):  # SIGTERM/SIGINT end the echo
        # EventsExecutor (7.1.6) is driven by spin_once: its spin() delivered 1 round trip in
        # 3-6 s here (docs/performance.md)
        while True:
            ex.spin_once(timeout_sec=0.1)


def measure(duration_s: float = 5.0, domain: int = 87, executor: str = "single",
            timeout_s: float = 30.0, ping: str = "single") -> dict[str, Any]:
    """Run the echo process and ping for ``duration_s``; returns round trips per second.

    Returns
    -------
    dict
        ``round_trips_per_s``, ``rtt_us_p50``, ``rtt_us_p99``, ``round_trips``, ``executor``.
    """
    from dcsms_ros.rosenv import keep_discovery_local

    keep_discovery_local()  # the pinger here, the echo process through its environment
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, __file__, "--echo", "--executor", executor],
                            env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        proc.stdout.readline()
        return _ping(duration_s, executor, timeout_s, ping)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _hot_waiter(node: Any) -> tuple[Any, Any]:
    """A detached pong subscription and a function that waits for and takes one message."""
    from geometry_msgs.msg import TwistStamped
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    from dcsms_ros.ros.callbackgroups import DetachedGroup

    sub = node.create_subscription(TwistStamped, PONG, lambda m: None, 1,
                                   callback_group=DetachedGroup())
    ws = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, node.context.handle)
    h = sub.handle

    def wait(timeout_s: float) -> bool:
        got = h.take_message(TwistStamped, False)
        if got is None:
            ws.clear_entities()
            ws.add_subscription(h)
            ws.wait(int(timeout_s * 1e9))
            got = h.take_message(TwistStamped, False)
        return got is not None

    return sub, wait


def _ping(duration_s: float, executor: str, timeout_s: float,
          ping: str = "single") -> dict[str, Any]:
    import numpy as np
    import rclpy
    from geometry_msgs.msg import TwistStamped

    rclpy.init()
    try:
        node = rclpy.create_node("bench_ping")
        pub = node.create_publisher(TwistStamped, PING, 1)
        got: list[int] = []
        node.create_subscription(TwistStamped, PONG, lambda m: got.append(1), 1)
        ex = _executor("events" if ping == "events" else "single")
        ex.add_node(node)
        msg = TwistStamped()
        deadline = time.monotonic() + timeout_s
        while pub.get_subscription_count() == 0 or node.count_publishers(PONG) == 0:
            ex.spin_once(timeout_sec=0.05)
            if time.monotonic() > deadline:
                raise TimeoutError("echo process not discovered")
        # warm-up: the first exchanges also complete discovery of the pong subscription
        while len(got) < 20 and time.monotonic() < deadline:
            pub.publish(msg)
            ex.spin_once(timeout_sec=0.1)
        rtts = []
        end = time.monotonic() + duration_s
        if ping == "hot":
            _sub, wait = _hot_waiter(node)
            while wait(0.2):  # warm-up of the second subscription
                pass
            pub.publish(msg)
            wait(2.0)
            while time.monotonic() < end:
                t0 = time.perf_counter()
                pub.publish(msg)
                wait(0.5)
                rtts.append(time.perf_counter() - t0)
        while ping != "hot" and time.monotonic() < end:
            got.clear()
            t0 = time.perf_counter()
            pub.publish(msg)
            while not got:
                ex.spin_once(timeout_sec=0.5)
                if time.monotonic() > end + 1.0:
                    break
            rtts.append(time.perf_counter() - t0)
        r = np.asarray(rtts)
        return {"round_trips_per_s": float(r.size / r.sum()), "round_trips": int(r.size),
                "rtt_us_p50": float(np.percentile(r, 50) * 1e6),
                "rtt_us_p99": float(np.percentile(r, 99) * 1e6), "executor": executor}
    finally:
        rclpy.try_shutdown()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--echo", action="store_true", help="run the echo side")
    ap.add_argument("--executor", choices=("single", "events", "hot"), default="single")
    ap.add_argument("--ping", choices=("single", "hot", "events"), default="single")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--domain", type=int, default=87)
    a = ap.parse_args()
    if a.echo:
        echo(a.executor)
    else:
        print(measure(a.seconds, a.domain, a.executor, ping=a.ping))


if __name__ == "__main__":
    main()
