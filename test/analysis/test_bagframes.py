"""The frames of the bag writer process, split however the pipe cuts them."""

from __future__ import annotations

import json

import pytest

from dcsms_ros.analysis.bagframes import (
    CLOSE,
    HEADER,
    MESSAGE,
    TOPIC,
    FrameReader,
    pack_frame,
    pack_json,
    pack_messages,
)


def _stream() -> tuple[bytes, list[tuple[int, int, int, int, bytes]]]:
    msgs = [(i % 3, bytes([i]) * (i % 7), i + 1, 10**18 + i) for i in range(50)]
    data = (pack_json(TOPIC, {"topic": "/a"}, 2) + pack_messages(msgs) + pack_frame(CLOSE))
    want = [(TOPIC, 2, -1, 0, json.dumps({"topic": "/a"}).encode())]
    want += [(MESSAGE, tid, seq, t, d) for tid, d, seq, t in msgs]
    want += [(CLOSE, 0, -1, 0, b"")]
    return data, want


@pytest.mark.parametrize("piece", [1, 2, HEADER.size - 1, HEADER.size, 100, 1 << 20])
def test_every_frame_comes_back_whatever_the_pieces(piece: int) -> None:
    """Fed in pieces of any size (a frame cut in its header, in its payload, or many frames
    in one read), the reader gives back exactly the frames written, in order."""
    data, want = _stream()
    reader = FrameReader()
    got = []
    for at in range(0, len(data), piece):
        got += list(reader.feed(data[at:at + piece]))
    assert got == want
    assert not reader.partial


def test_a_cut_frame_is_reported_and_held() -> None:
    """The bytes of a frame not yet complete stay until its rest arrives."""
    frame = pack_frame(MESSAGE, 1, b"xyz", 7, 42)
    reader = FrameReader()
    assert list(reader.feed(frame[:-1])) == []
    assert reader.partial
    assert list(reader.feed(frame[-1:])) == [(MESSAGE, 1, 7, 42, b"xyz")]
    assert not reader.partial
