"""McapBagWriter's per-message path (the recorder's): the bag rosbags' writer gives, message for
message, also when single messages and row blocks share chunks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis import mcapchunks
from dcsms_ros.analysis.bagio import BagWriter
from dcsms_ros.analysis.mcapwrite import McapBagWriter

TOPICS = ("/dcsms/velocity/stage1", "/dcsms/velocity/stage2")


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    with Reader(path) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


@pytest.mark.parametrize("chunk_bytes", [700, 64 << 10])
def test_single_messages_and_rows_read_back_in_order(tmp_path: Path, chunk_bytes: int) -> None:
    """Interleaved single messages (out of time order across topics, as a recorder receives
    them) and a row block: every message, its log time and bytes, as written and as rosbags'
    own writer stores the same sequence; small chunks split the singles between chunks."""
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
    for w in (ours, ref):
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
    file = next((tmp_path / "ours").glob("*.mcap"))
    channels, chunks = mcapchunks.summary(file)
    indexed = []
    for block in mcapchunks.iter_blocks(file, set(channels), chunks):
        payloads = ([bytes(r) for r in block.rows] if block.rows is not None
                    else [bytes(b) for b in block.buffers or []])
        indexed += [(channels[block.channel][0], int(t), b)
                    for t, b in zip(block.log_ns, payloads, strict=True)]
    assert sorted(indexed) == sorted(got)
