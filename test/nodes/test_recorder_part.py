"""The recorder in a node's own process (one process per node, ``dcsms up --record``), over real
rclpy: every message a hot-path writer publishes is in the part, with its bytes, in order, and
counted as published; a DDS reader still gets what is published once it is matched; the part's
flush runs outside the hot-path lock."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from geometry_msgs.msg import TwistStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.gaps import PUBLISHED_KEY
from dcsms_ros.errors import DcsmsError
from dcsms_ros.graph import RECORD_PART_ENV, RECORD_TOPICS_ENV
from dcsms_ros.nodes.recorder_part import PART_BATCH, attach
from dcsms_ros.protocols.matched import LANE_MATCH_REFRESH_NS
from dcsms_ros.ros import qos
from dcsms_ros.ros.callbackgroups import UnlockedGroup
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.hosted import Hosted
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.intraprocess import DirectPublisher
from dcsms_ros.ros.serialized import serialize

VOLATILE, DURABLE, OTHER = "/part/volatile", "/part/durable", "/part/other"


class Writer(GraphNode, Hosted):
    """A node with three hot-path writers (a volatile, a durable and an unrecorded one)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("part_writer", **kwargs)
        self.hot = HotPath(self)
        self.vol = self.hot.publisher(TwistStamped, VOLATILE, qos.stream_pub(False))
        self.dur = self.hot.publisher(TwistStamped, DURABLE, qos.stream_pub(True, durable=True))
        self.other = self.hot.publisher(TwistStamped, OTHER, qos.stream_pub(False))


def _msgs(n: int, k0: int = 0) -> list[bytes]:
    t = (np.arange(n, dtype=np.int64) + k0) * 500_000
    return [bytes(b) for b in cdr.encode_stamped(cdr.TWIST_STAMPED, t, "stage1",
                                                 np.arange(6.0 * n).reshape(n, 6))]


def _matched_reader(node: Writer, reader: Node, got: list[Any]) -> Any:
    """A best-effort DDS reader of VOLATILE (200 deep) on ``reader``, into ``got``, once it is
    matched on both sides (a best-effort reader drops what comes from a writer it has not
    matched yet) and the writer's count, cached for LANE_MATCH_REFRESH_NS, was asked since: the
    contract is every message from at most that long after the match."""
    keep = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
    sub = reader.create_subscription(TwistStamped, VOLATILE, got.append, keep, raw=True)
    end = time.monotonic() + 10.0
    while (node.vol.get_subscription_count() == 0 or sub.get_publisher_count() == 0) \
            and time.monotonic() < end:
        time.sleep(0.01)
    time.sleep(2 * LANE_MATCH_REFRESH_NS * 1e-9)
    return sub


def _rows(path: Path) -> list[tuple[str, bytes]]:
    """(topic, bytes) of every message in the part at ``path``, in its order."""
    with Reader(path) as r:
        return [(c.topic, bytes(raw)) for c, _, raw in r.messages()]


def _spin(ctx: Any, reader: Node, got: list[Any], n: int) -> None:
    """Spin ``reader`` until ``got`` holds ``n`` messages (10 s at most)."""
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(reader)
    end = time.monotonic() + 10.0
    while len(got) < n and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    ex.shutdown()


def test_every_published_message_is_in_the_part_and_dds_only_with_a_reader(
        ctx: Any, tmp_path: Path) -> None:
    node = Writer(context=ctx)
    reader = Node("part_reader", context=ctx)
    got: list[Any] = []
    try:
        part = attach(node, {RECORD_PART_ENV: str(tmp_path / "part"),
                             RECORD_TOPICS_ENV: f"{VOLATILE} {DURABLE} /part/absent"})
        assert part is not None
        assert isinstance(node.vol, DirectPublisher) and node.vol.observed
        assert not node.other.observed and not node.other.wanted()  # not asked for
        assert node.vol.wanted() and node.vol.get_subscription_count() == 0
        first = _msgs(5)
        for m in first:
            node.vol.publish(m)
            node.dur.publish(m)
        sub = _matched_reader(node, reader, got)
        second = _msgs(5, 5)
        for m in second:
            node.vol.publish(m)
        _spin(ctx, reader, got, 5)
        # on DDS only what was published while the reader was matched
        assert [bytes(m) for m in got] == second
        reader.destroy_subscription(sub)
        path = part.finish()
    finally:
        reader.destroy_node()
        node.destroy_node()
    rows = _rows(path)
    assert [m for t, m in rows if t == VOLATILE] == first + second
    assert [m for t, m in rows if t == DURABLE] == first
    info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert json.loads(info["custom_data"][PUBLISHED_KEY]) == {VOLATILE: 10, DURABLE: 5}


def test_the_hot_thread_writes_whole_batches_in_publication_order_and_the_rest_at_the_end(
        ctx: Any, tmp_path: Path) -> None:
    node = Writer(context=ctx)
    try:
        part = attach(node, {RECORD_PART_ENV: str(tmp_path / "part"),
                             RECORD_TOPICS_ENV: f"{VOLATILE} {DURABLE}"})
        assert part is not None
        msgs = _msgs(2 * PART_BATCH + 7)
        for i, m in enumerate(msgs):
            (node.vol if i % 3 else node.dur).publish(m)
            written = sum(part.writer.counts.values())
            assert written == (i + 1) // PART_BATCH * PART_BATCH, i  # whole batches only
        path = part.finish()
    finally:
        node.destroy_node()
    rows = _rows(path)
    assert sorted(m for _, m in rows) == sorted(msgs)
    assert [m for t, m in rows if t == VOLATILE] == [m for i, m in enumerate(msgs) if i % 3]
    assert [m for t, m in rows if t == DURABLE] == [m for i, m in enumerate(msgs) if not i % 3]


def test_work_handed_over_is_written_as_published_and_published_once_a_reader_is_there(
        ctx: Any, tmp_path: Path) -> None:
    """publish_later while the part alone takes the topic (no lane, no DDS reader): the part
    encodes in its batch, the same bytes in publication order among the messages published
    as bytes; once a DDS reader is matched each one is encoded and published at once."""
    node = Writer(context=ctx)
    reader = Node("part_reader", context=ctx)
    got: list[Any] = []
    enc = cdr.StampedWriter(cdr.TWIST_STAMPED, "stage1", 6)
    values = [[float(6 * k + j) for j in range(6)] for k in range(2 * PART_BATCH)]
    want = [enc.encode(500_000 * k, v) for k, v in enumerate(values)]
    try:
        part = attach(node, {RECORD_PART_ENV: str(tmp_path / "part"),
                             RECORD_TOPICS_ENV: VOLATILE})
        assert part is not None and isinstance(node.vol, DirectPublisher)
        half = PART_BATCH
        assert node.vol.lane is not None and not node.vol.lane.lanes  # one process per node
        for k in range(half):  # every third as bytes: the order must hold across both
            if k % 3:
                node.vol.publish_later(enc.encode, 500_000 * k, values[k])
            else:
                node.vol.publish(want[k])
            if k == 1:  # the work itself went to the part, not its bytes
                assert part._batch[-1][2].__class__ is tuple
        sub = _matched_reader(node, reader, got)
        for k in range(half, 2 * half):
            node.vol.publish_later(enc.encode, 500_000 * k, values[k])
        _spin(ctx, reader, got, half)
        assert [bytes(m) for m in got] == want[half:]
        reader.destroy_subscription(sub)
        path = part.finish()
    finally:
        reader.destroy_node()
        node.destroy_node()
    rows = _rows(path)
    assert [m for _, m in rows] == want


def test_without_the_variables_nothing_is_recorded_and_a_bad_part_is_one_error(
        ctx: Any, tmp_path: Path) -> None:
    node = Writer(context=ctx)
    try:
        assert attach(node, {}) is None and not node.vol.observed
        (tmp_path / "taken").mkdir()
        with pytest.raises(DcsmsError, match=f"{RECORD_PART_ENV}: .*exists already"):
            attach(node, {RECORD_PART_ENV: str(tmp_path / "taken"), RECORD_TOPICS_ENV: VOLATILE})
    finally:
        node.destroy_node()


def test_an_unlocked_group_timer_runs_outside_the_hot_lock(ctx: Any) -> None:
    """The part's flush (an UnlockedGroup job) runs while the hot loop holds its lock; an
    ordinary timer is wrapped and waits (the test can fail)."""
    node = Writer(context=ctx)
    done: dict[str, bool] = {}
    free = node.create_timer(10.0, lambda: done.setdefault("free", True),
                             callback_group=UnlockedGroup())
    locked = node.create_timer(10.0, lambda: done.setdefault("locked", True))
    serialize(node)
    assert node.hot is not None
    hold, release = threading.Event(), threading.Event()

    def holder() -> None:
        with node.hot.lock:
            hold.set()
            release.wait(5.0)

    threads = [threading.Thread(target=holder), threading.Thread(target=free.callback),
               threading.Thread(target=locked.callback)]
    try:
        threads[0].start()
        assert hold.wait(5.0)
        threads[1].start()
        threads[2].start()
        time.sleep(0.3)
        assert done == {"free": True}, done
        release.set()
        for t in threads:
            t.join(5.0)
        assert done == {"free": True, "locked": True}
    finally:
        release.set()
        node.destroy_node()
