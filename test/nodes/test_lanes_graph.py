"""Host lanes in real graphs: one process per node moves its samples on lanes, DDS carries
them only for a reader without a lane, and a lane reader hears a writer without one."""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from geometry_msgs.msg import TwistStamped
from node_helpers import executor_for, spin_until
from rclpy.node import Node
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from dcsms_ros.core import topics
from dcsms_ros.ros import qos
from dcsms_ros.ros.hostlane import LaneReader, LaneWriter
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.intraprocess import DirectPublisher
from dcsms_ros.ros.laneinput import DDS, LANES, MIXED, STATE_S, LaneInput

DCSMS = [sys.executable, "-m", "dcsms_ros.cli"]
LINE = re.compile(r"lanes: (\S+): (\d+) messages on lanes, (\d+) on DDS "
                  r"\((\d+) after a lane's reader left\), (\d+) lost")


def _lane_lines(logs: Path) -> dict[str, tuple[int, int, int]]:
    """Each writer's closing line: topic -> (on lanes, on DDS before any lane's reader left,
    lost)."""
    out: dict[str, tuple[int, int, int]] = {}
    for log in logs.glob("*.log"):
        for m in LINE.finditer(log.read_text()):
            out[m.group(1)] = (int(m.group(2)), int(m.group(3)) - int(m.group(4)),
                               int(m.group(5)))
    return out


def test_one_process_per_node_uses_lanes_and_dds_only_for_a_reader_without_one(ctx, tmp_path):
    """`dcsms up --realtime`, 3 s, with an outside DDS reader of one velocity: that topic goes
    on DDS too, every other per-sample topic on lanes only, and the outside reader gets the
    samples once each. A message a writer sends on DDS after a lane's reader left is not
    counted against it: that reader's DDS end is matched until its process leaves DDS, and a
    loaded host's controller still answered after the plant closed its lanes (1 force on DDS,
    2 of ~10 runs beside two more such runs)."""
    probe = rclpy.create_node("lane_probe", context=ctx)
    stamps: list[int] = []
    probe.create_subscription(
        TwistStamped, topics.DEFAULT.velocity("stage1"),
        lambda m: stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
        qos.stream_pub(False))
    ex = executor_for(ctx, probe)
    logs = tmp_path / "logs"
    seconds, rate = 3.0, 2000
    up = subprocess.Popen([*DCSMS, "up", "--realtime", "--mode", "DFBC+FFC", "--duration",
                           f"{seconds:g}", "--log-dir", str(logs), "--wait-for-subscribers",
                           topics.DEFAULT.velocity("stage1")],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 120
    while up.poll() is None and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)
    out = up.communicate(timeout=60)[0]
    ex.shutdown()
    assert up.returncode == 0, out
    lines = _lane_lines(logs)
    samples = int(seconds * rate)
    # the plant publishes every sample
    for topic in (topics.DEFAULT.sensors_raw, topics.DEFAULT.actuators_applied):
        assert lines[topic] == (samples, 0, 0), (topic, lines)
    # the decoupling answers the newest raw sample of a wake-up (it steps through all), so
    # how many it publishes is the host's speed, not the lanes' (a slow host's CI run without
    # SCHED_FIFO: 2,457 of 6,000, 49 % of the samples late): every velocity topic carries
    # the same answers, on lanes only where no reader lacks a lane
    answers = lines[topics.DEFAULT.velocity("ground")][0]
    assert answers >= samples // 10, lines  # a run, not a start-up that never got going
    assert lines[topics.DEFAULT.velocity("ground")] == (answers, 0, 0), lines
    assert lines[topics.DEFAULT.velocity("stage2")] == (answers, 0, 0), lines
    for topic in (topics.DEFAULT.force(c) for c in ("fb_stage1", "fb_stage2", "ff_stage1")):
        on_lanes, on_dds, lost = lines[topic]
        assert on_lanes >= answers // 10 and on_dds == 0 and lost == 0, (topic, lines)
    on_lanes, on_dds, lost = lines[topics.DEFAULT.velocity("stage1")]
    # the probe has no lane: DDS from the writer's match with it on (the graph, which the
    # plant waits for, may show it earlier)
    assert on_lanes == answers and on_dds >= answers // 2 and lost == 0, lines
    assert len(stamps) == len(set(stamps)) >= 0.9 * on_dds, len(stamps)  # best effort


class _Reader:
    """A node whose hot path reads ``/lane_test`` (a lane, one process per node)."""

    def __init__(self, ctx) -> None:
        self.node = Node("lane_reader", context=ctx)
        self.hot = HotPath(self.node)
        self.got: list[str] = []
        self.hot.subscribe(Header, "/lane_test", self._on, qos.stream_sub(True), raw=True)
        self.hot.start()

    def _on(self, data: bytes) -> None:
        self.got.append(rclpy.serialization.deserialize_message(data, Header).frame_id)


def _header(who: str, k: int) -> bytes:
    h = Header(frame_id=f"{who}{k}")
    h.stamp.sec = k
    return serialize_message(h)


def test_a_lane_reader_hears_a_writer_without_a_lane_once_and_the_lane_writers_copies_never(
        ctx):
    """A lane writer that also publishes on DDS (an outside reader is matched) and a plain DDS
    writer of the same topic: the lane reader gets each message of both exactly once; with
    the plain writer gone it reads the lane alone and leaves the DDS copies."""
    reader = _Reader(ctx)
    wnode = Node("lane_writer", context=ctx)
    whot = HotPath(wnode)
    lane_pub = whot.publisher(Header, "/lane_test", qos.stream_pub(True))
    assert isinstance(lane_pub, DirectPublisher) and lane_pub.lane is not None
    outside = Node("outside_reader", context=ctx)
    outside_got: list[str] = []
    outside.create_subscription(Header, "/lane_test", lambda m: outside_got.append(m.frame_id),
                                qos.stream_pub(True))
    plain = Node("plain_writer", context=ctx)
    plain_pub = plain.create_publisher(Header, "/lane_test", qos.stream_pub(True))
    ex = executor_for(ctx, wnode, outside, plain)
    lane_in = next(iter(reader.hot.lanes.inputs.values()))
    assert spin_until(ex, lambda: lane_pub.get_subscription_count() == 2
                      and lane_in.sub.get_publisher_count() == 2, 20.0)
    assert whot.lanes is not None
    whot.lanes.connect()  # the lane writer's hello; the reader's loop reads it within 10 ms
    assert spin_until(ex, lambda: lane_in.state(time.monotonic()) == MIXED, 5.0)
    for k in range(200):
        lane_pub.publish(_header("lane", k))
        plain_pub.publish(Header(frame_id=f"plain{k}"))
        ex.spin_once(timeout_sec=0.002)
    want = {f"lane{k}" for k in range(200)} | {f"plain{k}" for k in range(200)}
    assert spin_until(ex, lambda: set(reader.got) >= want, 20.0), len(reader.got)
    assert sorted(reader.got) == sorted(want)  # once each: the lane writer's DDS copies dropped
    assert lane_pub.on_dds == 200  # for the outside reader
    assert lane_in.state(time.monotonic()) == MIXED
    plain.destroy_publisher(plain_pub)
    assert spin_until(ex, lambda: lane_in.state(time.monotonic()) == LANES, 20.0)
    reader.got.clear()
    for k in range(200, 400):
        lane_pub.publish(_header("lane", k))
        ex.spin_once(timeout_sec=0.002)
    assert spin_until(ex, lambda: len(reader.got) >= 200, 20.0)
    time.sleep(0.2)
    assert reader.got == [f"lane{k}" for k in range(200, 400)]  # the lane only, in order
    assert spin_until(ex, lambda: len(outside_got) >= 390, 20.0), len(outside_got)
    reader.hot.stop()
    reader.hot.close_lanes()
    whot.close_lanes()
    ex.shutdown()


def test_a_lane_inputs_state_follows_a_hello_at_once_and_the_dds_count_within_state_s(
        ctx, tmp_path):
    """The state is kept for STATE_S (a real DDS reader's matched count), but a writer's hello
    or bye changes it at the next look: before the hello DDS, after it LANES; a second DDS
    writer without a lane shows as MIXED only once the kept state is STATE_S old."""
    node = Node("lane_state_reader", context=ctx)
    sub = node.create_subscription(Header, "/lane_state", lambda m: None, qos.stream_sub(True),
                                   raw=True)
    root = tmp_path / "lanes"
    lane_in = LaneInput(sub, LaneReader("/lane_state", root, "/lane_state_reader"))
    writers = [Node(f"lane_state_writer{i}", context=ctx) for i in range(2)]
    pubs = [writers[0].create_publisher(Header, "/lane_state", qos.stream_pub(True))]
    ex = executor_for(ctx, node, *writers)
    assert spin_until(ex, lambda: sub.get_publisher_count() == 1, 20.0)
    t = time.monotonic() + 1.0  # a clock of the test's own, past every kept state
    assert lane_in.state(t) == DDS  # no hello yet
    lane = LaneWriter("/lane_state", root)
    lane.refresh()  # says hello
    lane_in.poll()
    assert lane_in.state(t) == LANES  # at the same instant: the hello is seen at once
    pubs.append(writers[1].create_publisher(Header, "/lane_state", qos.stream_pub(True)))
    assert spin_until(ex, lambda: sub.get_publisher_count() == 2, 20.0)
    assert lane_in.state(t + 0.5 * STATE_S) == LANES  # kept
    time.sleep(2 * STATE_S)  # the DDS count itself is up to STATE_S old (a real clock)
    assert lane_in.state(t + 1.5 * STATE_S) == MIXED  # judged again: a writer without a lane
    lane.close()  # says bye
    lane_in.poll()
    assert lane_in.state(t + 1.6 * STATE_S) == DDS  # at once again
    lane_in.close()
    ex.shutdown()
