"""McapBagWriter's per-message path (the recorder's): the bag rosbags' writer gives, message for
message, also when single messages and row blocks share chunks."""

from __future__ import annotations

import resource
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis import mcapchunks
from dcsms_ros.analysis.bagio import BagWriter
from dcsms_ros.analysis.mcaprecords import MESSAGE_HEADER
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.errors import BagError

TOPICS = ("/dcsms/velocity/stage1", "/dcsms/velocity/stage2")


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with Reader(path) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


def _indexed(path: Path) -> list[tuple[str, int, bytes]]:
    """Every message as the chunk reader finds it through the message indexes."""
    file = next(path.glob("*.mcap"))
    channels, chunks = mcapchunks.summary(file)
    out = []
    for block in mcapchunks.iter_blocks(file, set(channels), chunks):
        payloads = ([bytes(r) for r in block.rows] if block.rows is not None
                    else [bytes(b) for b in block.buffers or []])
        out += [(channels[block.channel][0], int(t), b)
                for t, b in zip(block.log_ns, payloads, strict=True)]
    return out


@pytest.mark.parametrize("batched", [False, True])
@pytest.mark.parametrize("chunk_bytes", [700, 64 << 10])
def test_single_messages_and_rows_read_back_in_order(tmp_path: Path, chunk_bytes: int,
                                                     batched: bool) -> None:
    """Interleaved single messages (out of time order across topics, as a recorder receives
    them) and a row block: every message, its log time and bytes, as written and as rosbags'
    own writer stores the same sequence; small chunks split the singles between chunks, also
    within one batch (``write_all``), and each chunk's time range holds its messages."""
    rng = np.random.default_rng(3)
    t = 10**9 + np.arange(60, dtype=np.int64) * 500_000
    sent: list[tuple[str, int, bytes]] = []
    for k in range(40):
        topic = TOPICS[int(rng.integers(2))]
        jitter = int(rng.integers(-200_000, 200_000))  # receive times need not be ordered
        data = cdr.encode_stamped(cdr.TWIST_STAMPED, t[k:k + 1], "stage1",
                                  rng.normal(size=(1, 6)))[0]
        sent.append((topic, int(t[k]) + jitter, data))
    ours = McapBagWriter(tmp_path / "ours", chunk_bytes=chunk_bytes)
    ref = BagWriter(tmp_path / "ref", "mcap")
    for w in (ours, ref):
        for topic in TOPICS:
            w.add_topic(topic, cdr.TWIST_STAMPED)
        for msg in sent[:25]:
            w.write(*msg)
    rows = cdr.encode_stamped(cdr.TWIST_STAMPED, t[40:], "stage1", np.ones((20, 6)))
    ours.write_rows(t[40:], TOPICS[:1], [np.frombuffer(b"".join(rows), np.uint8).reshape(20, -1)])
    ref.write_many(TOPICS[0], t[40:], rows)
    if batched:
        ours.write_all(sent[25:])
    for w in (ref,) if batched else (ours, ref):
        for msg in sent[25:]:
            w.write(*msg)
    assert ours.counts == ref.counts
    ours.close()
    ref.close()
    got = _messages(tmp_path / "ours")
    assert len(got) == 60
    assert sorted(got) == sorted(_messages(tmp_path / "ref"))
    expected = sent[:25] + [(TOPICS[0], int(a), b) for a, b in zip(t[40:], rows, strict=True)]
    assert sorted(got) == sorted(expected + sent[25:])
    # the chunk reader finds the messages through the message indexes: each must point at
    # its record
    assert sorted(_indexed(tmp_path / "ours")) == sorted(got)
    file = next((tmp_path / "ours").glob("*.mcap"))
    channels, chunks = mcapchunks.summary(file)
    assert len(chunks) > (1 if chunk_bytes < 1000 else 0)
    for ch, block_times in zip(chunks, _chunk_times(file, channels, chunks), strict=True):
        assert ch.message_start_time == min(block_times)
        assert ch.message_end_time == max(block_times)


def _chunk_times(file: Path, channels: dict[int, tuple[str, str]],
                 chunks: list[Any]) -> list[list[int]]:
    """The log times of each chunk's messages, read chunk by chunk."""
    return [[int(t) for block in mcapchunks.iter_blocks(file, set(channels), [ch])
             for t in block.log_ns] for ch in chunks]


def test_unknown_topic_in_a_batch_keeps_what_came_before(tmp_path: Path) -> None:
    """A batch stops at a topic that was not added (BagError); the messages before it are
    written and counted, and the bag closes with them."""
    sent = _stream(4)
    w = McapBagWriter(tmp_path / "bag")
    for topic in TOPICS:
        w.add_topic(topic, cdr.TWIST_STAMPED)
    with pytest.raises(BagError, match="/nope was not added"):
        w.write_all([*sent[:3], ("/nope", sent[3][1], sent[3][2]), sent[3]])
    assert sum(w.counts.values()) == 3
    w.close()
    assert _messages(tmp_path / "bag") == sent[:3]


def _stream(n: int) -> list[tuple[str, int, bytes]]:
    t = 10**9 + np.arange(n, dtype=np.int64) * 500_000
    vel = cdr.encode_stamped(cdr.TWIST_STAMPED, t, "stage1", np.arange(6.0 * n).reshape(n, 6))
    return [(TOPICS[k % 2], int(t[k]), vel[k]) for k in range(n)]


def test_deferred_chunks_wait_for_flush(tmp_path: Path) -> None:
    """With ``defer_flush`` a write that fills a chunk leaves it in memory (the file keeps only
    its header) until :meth:`flush`, which writes every full chunk but not the open one;
    :meth:`close` writes the rest."""
    sent = _stream(400)
    w = McapBagWriter(tmp_path / "bag", chunk_bytes=4096, defer_flush=True)
    for topic in TOPICS:
        w.add_topic(topic, cdr.TWIST_STAMPED)
    w._f.flush()
    header = w.file.stat().st_size  # the MCAP header; the schema and channels wait too
    for msg in sent:
        w.write(*msg)
    w._f.flush()
    assert w.file.stat().st_size == header  # 400 messages of ~120 B: ~11 chunks held
    w.flush()
    w._f.flush()
    grown = w.file.stat().st_size
    assert grown > 400 * 100 * 0.8 / 4  # zstd shrinks the repeated bytes ~4x
    w.flush()  # nothing new is full: the open chunk stays in memory
    w._f.flush()
    assert w.file.stat().st_size == grown
    w.close()
    assert _messages(tmp_path / "bag") == sent
    assert sorted(_indexed(tmp_path / "bag")) == sorted(sent)


def test_flush_beside_writes_from_another_thread(tmp_path: Path) -> None:
    """A composed recorder writes on the driver thread while its executor flushes: every
    message arrives once, in order, and its index points at it; topics added mid-stream too."""
    sent = _stream(6000)
    late_topic = "/dcsms/velocity/ground"
    w = McapBagWriter(tmp_path / "bag", chunk_bytes=8192, defer_flush=True)
    for topic in TOPICS:
        w.add_topic(topic, cdr.TWIST_STAMPED)
    done = threading.Event()

    def flusher() -> None:
        while not done.is_set():
            w.flush()

    th = threading.Thread(target=flusher)
    th.start()
    try:
        for k, msg in enumerate(sent):
            if k == 3000:
                w.add_topic(late_topic, cdr.TWIST_STAMPED)
            w.write(*msg)
            if k >= 3000 and k % 3 == 0:
                w.write(late_topic, msg[1], msg[2])
    finally:
        done.set()
        th.join()
    w.close()
    extra = [(late_topic, t, b) for k, (_, t, b) in enumerate(sent) if k >= 3000 and k % 3 == 0]
    got = _messages(tmp_path / "bag")
    assert len(got) == len(sent) + len(extra)
    assert [m for m in got if m[0] != late_topic] == sent
    assert [m for m in got if m[0] == late_topic] == extra
    assert sorted(_indexed(tmp_path / "bag")) == sorted(sent + extra)


def test_write_after_close_is_refused_and_nothing_is_left_behind(tmp_path: Path) -> None:
    """A write racing the close either lands in the bag or is refused with BagError."""
    w = McapBagWriter(tmp_path / "bag", defer_flush=True)
    w.add_topic(TOPICS[0], cdr.TWIST_STAMPED)
    sent = [m for m in _stream(10) if m[0] == TOPICS[0]]
    for msg in sent:
        w.write(*msg)
    w.close()
    with pytest.raises(BagError, match="written after close"):
        w.write(*sent[0])
    assert _messages(tmp_path / "bag") == sent


def test_a_deferred_writer_s_writes_touch_no_new_memory(tmp_path: Path) -> None:
    """A node's part recorder writes on its real-time thread: with ``defer_flush`` the chunk
    buffers are made (and their pages touched) with the writer and reused once written, so
    three chunks' worth of batches fault no page in that thread; a growing ``bytearray``
    faulted 88-760 pages in one batch (~9 us each on this package's virtual machine)."""
    sent = _stream(64)
    w = McapBagWriter(tmp_path / "bag", chunk_bytes=1 << 20, defer_flush=True)
    for topic in TOPICS:
        w.add_topic(topic, cdr.TWIST_STAMPED)
    faults = written = 0
    t = 0
    while written < 3 << 20:
        batch = [(topic, t + k, data) for k, (topic, _, data) in enumerate(sent)]
        t += len(sent)
        before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        w.write_all(batch)
        faults += resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before
        written += sum(MESSAGE_HEADER + len(d) for _, _, d in batch)
        if t % (64 * 64) == 0:
            w.flush()  # the node's executor, once a second
    w.close()
    assert faults <= 8, faults  # the index arrays' growth at most
    assert sum(1 for _ in _messages(tmp_path / "bag")) == t
