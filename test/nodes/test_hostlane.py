"""Host lanes on real FIFOs between real processes (no ROS): delivery, loss, gone peers."""

from __future__ import annotations

import fcntl
import multiprocessing as mp
import os
import signal
import termios
import time
from pathlib import Path

import pytest

from dcsms_ros.ros import hostlane
from dcsms_ros.ros.hostlane import (
    PIPE_SIZE,
    LaneReader,
    LaneWriter,
    host_key,
    lane_root,
    topic_dir,
)

TOPIC = "/dcsms/velocity/stage1"
CTX = mp.get_context("fork")


def _queued(fd: int) -> int:
    """Bytes waiting in the pipe behind ``fd`` (either end)."""
    return int.from_bytes(fcntl.ioctl(fd, termios.FIONREAD, b"\0" * 4), "little")


def _write(root: str, n: int, size: int, tag: int, drops: mp.Queue) -> None:
    """A writer process: ``n`` messages of ``size`` bytes (``tag``, k as 4 bytes, filler) in
    bursts of 100, each once the lane holds less than 16 KiB: two such writers never fill
    even a default 64 KiB pipe, however late the reader is scheduled (a CI run lost 66 % to
    a starved reader when bursts were paced by time); puts how many its lane could not take."""
    w = LaneWriter(TOPIC, Path(root))
    w.refresh()
    (fd,) = w.lanes.values()
    end = time.monotonic() + 30.0
    for k in range(n):
        if k % 100 == 0:
            while _queued(fd) >= 16 << 10 and time.monotonic() < end:
                time.sleep(0.0002)
        w.write(bytes([tag]) + k.to_bytes(4, "little") + b"x" * (size - 5), time.time_ns())
    drops.put(w.table.drops)
    w.close()


def _drain(r: LaneReader, want: int, timeout_s: float = 20.0) -> list[tuple[bytes, int]]:
    got: list[tuple[bytes, int]] = []
    end = time.monotonic() + timeout_s
    while len(got) < want and time.monotonic() < end:
        got += r.read()
    return got


def test_every_message_of_two_writer_processes_arrives_whole_and_in_each_writers_order(
        tmp_path: Path) -> None:
    """Two processes write 20,000 messages each into one lane at once, never more than the
    pipe holds: the reader gets every one, each writer's in order, none torn (a frame is one
    atomic pipe write), with both hellos and byes. (A full lane's loss is counted: the next
    test.)"""
    r = LaneReader(TOPIC, tmp_path, "/dcsms/reader")
    n, size = 20_000, 120
    drops: mp.Queue = CTX.Queue()
    procs = [CTX.Process(target=_write, args=(str(tmp_path), n, size, tag, drops))
             for tag in (1, 2)]
    for p in procs:
        p.start()
    got = _drain(r, 2 * n, timeout_s=30.0)
    for p in procs:
        p.join(10)
    got += r.read()
    lost = drops.get(timeout=5) + drops.get(timeout=5)
    assert (len(got), lost) == (2 * n, 0)
    for tag in (1, 2):
        ks = [int.from_bytes(d[1:5], "little") for d, _ in got if d[0] == tag]
        assert ks == sorted(ks) and len(set(ks)) == len(ks)
    assert all(len(d) == size and d[5:] == b"x" * (size - 5) for d, _ in got)
    assert sorted(r.source.writers) == []  # both said bye
    r.close()


def test_a_reader_that_does_not_read_never_blocks_the_writer_and_its_loss_is_counted(
        tmp_path: Path) -> None:
    r = LaneReader(TOPIC, tmp_path, "/dcsms/reader")
    w = LaneWriter(TOPIC, tmp_path)
    assert not w.dds(1, 0, 200)  # one DDS reader, one lane
    t0 = time.monotonic()
    n = 20_000
    for k in range(n):
        w.write(k.to_bytes(4, "little") + b"y" * 200, time.time_ns())
    assert time.monotonic() - t0 < 5.0
    kept = len(_drain(r, n, timeout_s=0.5))
    assert w.table.drops == n - kept > 0
    assert kept * (200 + 4 + 12) <= PIPE_SIZE  # the pipe held what it could
    w.close()
    r.close()


def test_a_killed_reader_closes_its_lane_and_its_fifo_is_removed_by_the_next_reader(
        tmp_path: Path) -> None:
    ready = CTX.Event()

    def reader() -> None:
        LaneReader(TOPIC, tmp_path, "/dcsms/reader")
        ready.set()
        time.sleep(60)

    p = CTX.Process(target=reader)
    p.start()
    assert ready.wait(10)
    w = LaneWriter(TOPIC, tmp_path)
    w.refresh()
    assert len(w.lanes) == 1
    os.kill(p.pid, signal.SIGKILL)
    p.join(10)
    w.write(b"after", time.time_ns())  # EPIPE: nobody reads it any more
    assert w.lanes == {} and w.left == 1
    stale = list(topic_dir(TOPIC, tmp_path).iterdir())
    assert len(stale) == 1  # killed: it could not remove its FIFO
    r = LaneReader(TOPIC, tmp_path, "/dcsms/reader")
    assert [f.name for f in topic_dir(TOPIC, tmp_path).iterdir()] == [r.path.name]
    r.close()
    assert list(topic_dir(TOPIC, tmp_path).iterdir()) == []


def test_a_reader_that_closes_is_counted_as_left_and_its_dds_end_gets_the_next_message(
        tmp_path: Path) -> None:
    """A reader removes its FIFO when it closes: the writer's next look closes that lane and
    counts the reader as left; its DDS reader, still matched while its process goes, is then
    served by DDS. The writer's own close counts nothing."""
    r = LaneReader(TOPIC, tmp_path, "/dcsms/reader")
    w = LaneWriter(TOPIC, tmp_path)
    assert not w.dds(1, 0, 10) and len(w.lanes) == 1 and w.left == 0
    r.close()
    assert w.dds(1, 10**9, 10) and w.lanes == {} and w.left == 1
    w.close()
    assert w.left == 1


def test_a_killed_writer_is_forgotten_by_its_reader(tmp_path: Path) -> None:
    r = LaneReader(TOPIC, tmp_path, "/dcsms/reader")

    def writer() -> None:
        w = LaneWriter(TOPIC, tmp_path)
        w.refresh()
        w.write(b"hi", time.time_ns())
        time.sleep(60)

    p = CTX.Process(target=writer)
    p.start()
    assert [d for d, _ in _drain(r, 1)] == [b"hi"]
    assert r.writers(0.0) == 1
    os.kill(p.pid, signal.SIGKILL)
    p.join(10)
    assert r.writers(time.monotonic() + 1.0) == 0  # no bye: its process is gone
    r.close()


def test_a_writer_opens_no_lane_to_a_fifo_nobody_reads(tmp_path: Path) -> None:
    d = topic_dir(TOPIC, tmp_path)
    d.mkdir(parents=True)
    os.mkfifo(d / "999999.1")
    w = LaneWriter(TOPIC, tmp_path)
    assert w.dds(1, 0, 10) and w.lanes == {}


def test_a_reader_the_graph_shows_without_a_lane_gets_dds_whatever_the_matched_count(
        tmp_path: Path) -> None:
    """Two lane readers (one of them not matched on DDS yet) and a recorder process: DDS
    matched two readers, there are two lanes, but the recorder has none."""
    graph = ["/dcsms/fb_stage1", "/dcsms/mode_switch"]
    readers = [LaneReader(TOPIC, tmp_path, n) for n in graph]
    w = LaneWriter(TOPIC, tmp_path, lambda: (graph, True), lambda: len(graph))
    assert not w.dds(2, 0, 100) and len(w.lanes) == 2 and w.outside == 0
    graph.append("/dcsms_recorder")  # the graph count changed: asked again at the next look
    assert w.dds(2, 10**9, 100) and w.outside == 1
    graph.pop()
    assert not w.dds(2, 2 * 10**9, 100)
    for r in readers:
        r.close()


def test_lanes_are_keyed_by_namespaces_and_domain(tmp_path: Path) -> None:
    netns, pidns = (os.stat(f"/proc/self/ns/{k}").st_ino for k in ("net", "pid"))
    assert host_key(17) == f"{netns}-{pidns}-17"
    assert lane_root(17, tmp_path) != lane_root(18, tmp_path)
    assert lane_root(17, tmp_path).parent.stat().st_mode & 0o777 == 0o700


@pytest.mark.parametrize(("env", "on"), [({}, True), ({"DCSMS_HOST_LANES": "0"}, False),
                                         ({"DCSMS_HOST_LANES": "off"}, False),
                                         ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}, False),
                                         ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, True)])
def test_lanes_are_on_unless_turned_off_or_discovery_is(monkeypatch: pytest.MonkeyPatch,
                                                        env: dict[str, str], on: bool) -> None:
    monkeypatch.delenv("DCSMS_HOST_LANES", raising=False)
    monkeypatch.delenv("ROS_AUTOMATIC_DISCOVERY_RANGE", raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert hostlane.enabled() is on


def test_a_message_too_long_for_a_lane_is_refused(tmp_path: Path) -> None:
    r = LaneReader(TOPIC, tmp_path, "/dcsms/reader")
    w = LaneWriter(TOPIC, tmp_path)
    w.refresh()
    assert not w.write(b"z" * 5000, 0)
    assert w.write(b"z" * 4084, 0)
    assert [len(d) for d, _ in r.read()] == [4084]
    w.close()
    r.close()


def test_a_refused_pipe_size_is_said_and_the_lane_still_works(tmp_path: Path) -> None:
    """The kernel refuses a pipe above fs.pipe-max-size to a process without the privilege
    (128 MiB: refused to root too, fs.pipe-max-size being 1 MiB here): the reader says why
    and what it got, and the lane carries messages in the smaller pipe; the default size is
    granted and nothing is said."""
    big = LaneReader(TOPIC, tmp_path, "/dcsms/big", pipe_size=1 << 27)
    ok = LaneReader(TOPIC, tmp_path, "/dcsms/ok")
    try:
        if big.capacity >= 1 << 27:
            pytest.skip("the kernel granted 128 MiB (CAP_SYS_RESOURCE): no refusal to show")
        assert big.refused and 0 < big.capacity < 1 << 27
        assert ok.refused == "" and ok.capacity == hostlane.PIPE_SIZE
        w = LaneWriter(TOPIC, tmp_path)
        w.refresh()
        assert len(w.lanes) == 2 and w.write(b"x" * 100, 7)
        assert _drain(big, 1) == _drain(ok, 1) == [(b"x" * 100, 7)]
        w.close()
    finally:
        big.close()
        ok.close()
