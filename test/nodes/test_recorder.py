"""Recorder over real DDS: exact counts, latched topics, gaps, SIGINT/SIGTERM leave a full bag."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.gaps import TopicStats
from dcsms_ros.analysis.mcapwrite import CHUNK_MAX_AGE_S
from dcsms_ros.cli import main
from dcsms_ros.cli.deploy import bag_published
from dcsms_ros.cli.record import recorder_command

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import TwistStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from std_msgs.msg import String

from dcsms_ros.nodes.recorder import recorder_ready

V1, V2, MODE = "/dcsms/velocity/stage1", "/dcsms/velocity/stage2", "/dcsms/mode"


class Graph:
    """A publisher node in its own context and ROS domain, and a ``dcsms record`` child."""

    def __init__(self, tmp: Path, domain: int) -> None:
        self.domain = domain
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain),
                        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=self.domain)
        self.node = Node("test_publisher", context=self.ctx)
        self.bag = tmp / "bag"
        self.proc: subprocess.Popen[str] | None = None
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.mode = self.node.create_publisher(String, MODE, latched)
        self.pubs = {t: self.node.create_publisher(TwistStamped, t, 1000) for t in (V1, V2)}
        self.sent = {V1: 0, V2: 0}

    def start_recorder(self, wait: tuple[str, ...] = (V1, V2), tty: int | None = None) -> None:
        """``tty``: a terminal's descriptor for the recorder's output (default: pipes)."""
        out = subprocess.PIPE if tty is None else tty
        self.proc = subprocess.Popen([*recorder_command(self.bag), "--json"], env=self.env,
                                     stdout=out, stderr=out, text=True)
        end = time.monotonic() + 30.0
        while not recorder_ready(self.node, wait):
            assert self.proc.poll() is None, self.proc.communicate()
            assert time.monotonic() < end, "recorder did not subscribe within 30 s"
            time.sleep(0.05)
        time.sleep(0.3)  # let the reliable readers finish matching

    def publish(self, topic: str, k: int) -> None:
        m = TwistStamped()
        m.header.frame_id = topic.rsplit("/", 1)[1]
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(k) * 500_000, 1_000_000_000)
        m.twist.linear.z = float(k)
        self.pubs[topic].publish(m)
        self.sent[topic] += 1

    def stream(self, ks: Any, topic: str = V1, rate_hz: float = 2000.0) -> None:
        t0 = time.perf_counter()
        for i, k in enumerate(ks):
            self.publish(topic, k)
            while time.perf_counter() < t0 + (i + 1) / rate_hz:
                pass

    def stop(self, sig: int = signal.SIGINT) -> tuple[int, dict[str, Any], str]:
        assert self.proc is not None
        self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=30)
        return self.proc.returncode, (json.loads(out) if out.strip() else {}), err

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


@pytest.fixture
def graph(tmp_path: Path, domain: int) -> Iterator[Graph]:
    """A fresh publisher + recorder pair in this test's own ROS domain."""
    g = Graph(tmp_path, domain)
    yield g
    g.close()


def _bag(path: Path) -> dict[str, list[bytes]]:
    assert (path / "metadata.yaml").is_file() and not path.with_name("bag.partial").exists()
    with Reader(path) as r:
        meta = {c.topic: c.msgcount for c in r.connections}
        out: dict[str, list[bytes]] = {t: [] for t in meta}
        for c, _, raw in r.messages():
            out.setdefault(c.topic, []).append(bytes(raw))
    assert meta == {t: len(v) for t, v in out.items()}
    return out


def _mcap_counts(path: Path) -> dict[str, int]:
    """Per-topic counts of every message the independent mcap + mcap_ros2 readers decode."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts: dict[str, int] = {}
    for f in sorted(path.glob("*.mcap")):
        with f.open("rb") as fh:
            reader = make_reader(fh, decoder_factories=[DecoderFactory()])
            for _, channel, _, _ in reader.iter_decoded_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
    return counts


def _z(msgs: list[bytes]) -> np.ndarray:
    return cdr.decode_batch(cdr.TWIST_STAMPED, msgs).fields["twist"][:, 2]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP],
                         ids=["SIGINT", "SIGTERM", "SIGHUP"])
def test_exact_counts_latched_and_clean_signal(graph: Graph, sig: int) -> None:
    """N messages and a latched mode recorded exactly, alike in rosbags and mcap; exit 0."""
    graph.mode.publish(String(data="FBC"))  # before the recorder exists: transient local
    graph.start_recorder()
    graph.stream(range(3000))
    time.sleep(0.5)  # publisher stopped first: the count is exactly what it sent
    rc, rep, err = graph.stop(sig)
    assert rc == 0 and "Traceback" not in err, err
    msgs = _bag(graph.bag)
    assert {t: len(v) for t, v in msgs.items()} == {MODE: 1, V1: 3000, V2: 0}
    # the same recording through the independent readers (a topic with no message has none)
    assert _mcap_counts(graph.bag) == {MODE: 1, V1: 3000}
    assert cdr.decode_string(msgs[MODE][0]) == "FBC"
    np.testing.assert_array_equal(_z(msgs[V1]), np.arange(3000))
    counts = {t["topic"]: t["count"] for t in rep["topics"]}
    assert counts == {MODE: 1, V1: 3000, V2: 0} and not rep["gaps"]
    # what was published, from the writers' sequence numbers, left in the bag's metadata
    assert bag_published(graph.bag) == {MODE: 1, V1: 3000}


def test_a_closed_terminal_stops_the_recording_cleanly(graph: Graph) -> None:
    """The terminal of a recording closes (an SSH session dropped): the recorder gets SIGHUP,
    closes its bag with every message as after Ctrl-C and exits 0, though its report can no
    longer be printed there (a write to the terminal fails from the hang-up on)."""
    master, slave = os.openpty()
    try:
        graph.start_recorder(tty=slave)
    finally:
        os.close(slave)
    graph.stream(range(1000))
    time.sleep(0.5)
    os.close(master)  # the terminal is gone
    assert graph.proc is not None
    graph.proc.send_signal(signal.SIGHUP)
    assert graph.proc.wait(30) == 0
    msgs = _bag(graph.bag)
    assert len(msgs[V1]) == 1000 and not msgs.get(V2)


def test_a_killed_recorder_s_bag_is_recovered(graph: Graph,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """SIGKILL, no clean-up at all: the bag stays unfinished (``bag.partial``); `dcsms recover`
    gives back every message received more than CHUNK_MAX_AGE_S before the kill, in order
    (before it closed chunks by age, a slow recording's whole first 4 MB stayed in memory)."""
    graph.start_recorder()
    graph.stream(range(2000))
    time.sleep(CHUNK_MAX_AGE_S + 1.0)  # the open chunk is older than that: flushed
    assert graph.proc is not None
    graph.proc.kill()
    graph.proc.wait(10)
    assert graph.bag.with_name("bag.partial").is_dir() and not graph.bag.exists()
    assert main(["recover", str(graph.bag)]) == 0
    assert "not closed; " in capsys.readouterr().out
    np.testing.assert_array_equal(_z(_bag(graph.bag)[V1]), np.arange(2000))


def test_signal_mid_stream_keeps_a_contiguous_prefix(graph: Graph) -> None:
    """SIGTERM while publishing: exit 0; the bag holds messages 0..n-1 in order, n >= sent."""
    graph.start_recorder()
    stop = threading.Event()

    def run() -> None:
        k = 0
        while not stop.is_set() and k < 20_000:
            graph.stream([k], rate_hz=1e9)
            k += 1
            time.sleep(0.001)

    th = threading.Thread(target=run)
    th.start()
    time.sleep(1.5)
    sent_before = graph.sent[V1]
    assert graph.proc is not None
    graph.proc.send_signal(signal.SIGTERM)
    out, err = graph.proc.communicate(timeout=30)
    stop.set()
    th.join()
    assert graph.proc.returncode == 0 and "Traceback" not in err, err
    z = _z(_bag(graph.bag)[V1])
    assert sent_before > 100 and sent_before <= z.size <= graph.sent[V1]
    np.testing.assert_array_equal(z, np.arange(z.size))
    assert not json.loads(out)["gaps"]


def test_time_gap_reported(graph: Graph) -> None:
    """A stream with a missing stamp is reported as one time gap; a clean one has none."""
    graph.start_recorder()
    ks = np.arange(1000)
    graph.stream(ks, V1)
    graph.stream(np.delete(ks, 500), V2)
    time.sleep(0.5)
    rc, rep, err = graph.stop()
    assert rc == 0, err
    by = {t["topic"]: t for t in rep["topics"]}
    assert by[V1]["time_gaps"] == 0 and by[V1]["count"] == 1000
    assert by[V2]["time_gaps"] == 1 and by[V2]["count"] == 999 and rep["gaps"]
    assert by[V2]["gap_examples_ns"] == [[499 * 500_000, 501 * 500_000]]
    assert by[V2]["median_period_ns"] == 500_000 and by[V2]["seq_gaps"] == 0


def test_sequence_gaps_and_restarts() -> None:
    """publication_sequence_number: a jump counts the missing messages; a decrease a restart."""
    st = TopicStats("/t", cdr.TWIST_STAMPED, stamped=False)
    assert st.published is None
    for seq in (1, 2, 3, 7, 8):
        st.add(seq, None, 0)
    assert st.published == 8  # 5 received of 8 published
    for seq in (1, 2):
        st.add(seq, None, 0)
    assert (st.count, st.seq_gaps, st.seq_missing, st.restarts) == (7, 1, 3, 1)
    assert st.published is None  # after a restart the total is not known
    st.set_publishers(2)  # interleaved numbering is not checked, nor the return to one
    for seq in (3, 50, 4, 51):
        st.add(seq, None, 0)
    st.set_publishers(1)
    for seq in (52, 53):
        st.add(seq, None, 0)
    assert (st.count, st.seq_gaps, st.restarts) == (13, 1, 1)


def test_a_new_publisher_between_discoveries_is_not_a_restart() -> None:
    """A second publisher that starts before the recorder's next discovery (every node writes
    /diagnostics) interleaves its own numbers: asked at the first jump, the topic's publisher
    count stops the checks instead of counting restarts and gaps; one publisher still has
    its restarts counted."""
    count = [1]
    st = TopicStats("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", stamped=False,
                    publishers=lambda: count[0])
    for seq in (1, 2, 3):
        st.add(seq, None, 0)
    count[0] = 2  # a second node's writer, not known yet to the recorder's set_publishers
    for seq in (1, 4, 2, 5, 3):
        st.add(seq, None, 0)
    assert (st.count, st.restarts, st.seq_gaps, st.checked) == (8, 0, 0, False)
    count[0] = 1
    alone = TopicStats("/t", cdr.TWIST_STAMPED, publishers=lambda: count[0])
    for seq in (1, 2, 1, 5):
        alone.add(seq, None, 0)
    assert (alone.restarts, alone.seq_gaps, alone.seq_missing) == (1, 1, 3)


def test_a_late_second_publisher_is_not_counted_as_restarts(ctx, tmp_path: Path) -> None:
    """Over DDS: the recorder subscribed while the topic had one writer; a second writer
    starts before its next discovery and both publish, interleaved (what every node does on
    /diagnostics): no restart and no sequence gap is reported, and every message is kept."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from dcsms_ros.nodes.recorder import Recorder

    rec = Recorder(str(tmp_path / "bag"), ["/probe_diag"], context=ctx, parameter_overrides=[
        Parameter("discovery_period_s", value=1000.0), Parameter("report_period_s", value=0.0)])
    pubs_node = rclpy.create_node("writers", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(rec)
    ex.add_node(pubs_node)
    try:
        qos = QoSProfile(depth=100)
        first = pubs_node.create_publisher(String, "/probe_diag", qos)
        end = time.monotonic() + 10.0
        while "/probe_diag" not in rec.stats and time.monotonic() < end:
            rec.discover()
            ex.spin_once(timeout_sec=0.05)
        while first.get_subscription_count() == 0 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        for k in range(3):
            first.publish(String(data=f"a{k}"))
        second = pubs_node.create_publisher(String, "/probe_diag", qos)
        while second.get_subscription_count() == 0 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        for k in range(5):  # interleaved: a3 b0 a4 b1 ...
            first.publish(String(data=f"a{k + 3}"))
            second.publish(String(data=f"b{k}"))
        st = rec.stats["/probe_diag"]
        while st.count < 13 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        assert (st.count, st.restarts, st.seq_gaps) == (13, 0, 0), st
    finally:
        rec.finish()
        rec.destroy_node()
        pubs_node.destroy_node()


def test_existing_out_is_one_line_error(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """An existing OUT is refused before any ROS work: one line, exit 2."""
    (tmp_path / "bag").mkdir()
    assert main(["record", str(tmp_path / "bag")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists already" in err


def test_duration_ends_recording(tmp_path: Path, domain: int) -> None:
    """--duration stops the recorder by itself; an empty recording is still a valid bag."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    proc = subprocess.run([sys.executable, "-m", "dcsms_ros.cli", "record", str(tmp_path / "b"),
                           "--duration", "1", "--storage", "sqlite3"], check=False, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "total 0 messages" in proc.stdout and _bag(tmp_path / "b") == {}
