"""The frames a bag writer process reads on its standard input (:mod:`.bagprocess`).

A frame is a fixed header, :data:`HEADER` (little endian: kind ``u8``, topic id ``u16``,
``seq`` ``i64``, ``t_ns`` ``i64``, payload length ``u32``), then the payload:

* :data:`TOPIC`: a topic the next messages use, its id in the header; the payload is JSON
  ``{"topic", "type", "qos", "stats", "stamped"}`` (``stats``: the writer process keeps the
  topic's :class:`~dcsms_ros.analysis.gaps.TopicStats`, from ``seq`` and the header stamps).
* :data:`MESSAGE`: one serialized message of the topic, ``t_ns`` its bag time, ``seq`` the
  publisher's message number (-1 when unknown).
* :data:`CUSTOM`: JSON ``{key: value}`` for the bag's ``custom_data``.
* :data:`LOST`: the writer dropped the topic's messages up to number ``seq``
  (:meth:`~dcsms_ros.analysis.gaps.TopicStats.lost_through`): a loss at the end of the
  recording, which no later message shows as a gap.
* :data:`CLOSE` / :data:`ABORT`: the last frame; close (metadata, rename into place) or remove
  the bag.

No ROS and no process here: :func:`pack_messages` and :class:`FrameReader` are tested with
plain bytes (test/analysis/test_bagframes.py).
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Iterator
from typing import Any

#: kind, topic id, seq, t_ns, payload length
HEADER = struct.Struct("<BHqqI")
MESSAGE, TOPIC, CUSTOM, CLOSE, ABORT, LOST = range(6)
#: Topic ids are a u16.
MAX_TOPICS = 1 << 16


def pack_frame(kind: int, topic_id: int = 0, payload: bytes = b"", seq: int = -1,
               t_ns: int = 0) -> bytes:
    """One frame."""
    return HEADER.pack(kind, topic_id, seq, t_ns, len(payload)) + payload


def pack_json(kind: int, value: Any, topic_id: int = 0) -> bytes:
    """A frame whose payload is ``value`` as JSON (:data:`TOPIC`, :data:`CUSTOM`)."""
    return pack_frame(kind, topic_id, json.dumps(value, sort_keys=True).encode())


def pack_messages(messages: Iterable[tuple[int, bytes, int, int]]) -> bytes:
    """:data:`MESSAGE` frames of ``(topic id, data, seq, t_ns)``, joined (one write)."""
    pack = HEADER.pack
    parts: list[bytes] = []
    add = parts.append
    for tid, data, seq, t_ns in messages:
        add(pack(MESSAGE, tid, seq, t_ns, len(data)))
        add(data)
    return b"".join(parts)


class FrameReader:
    """Split a byte stream into frames, whatever the pieces it arrives in.

    ``feed(piece)`` yields ``(kind, topic id, seq, t_ns, payload)`` for every frame completed
    by ``piece`` (the payload as ``bytes``); :attr:`partial` tells whether a frame is cut.
    """

    def __init__(self) -> None:
        self._buf = bytearray()

    @property
    def partial(self) -> bool:
        """True while the bytes fed so far end inside a frame."""
        return bool(self._buf)

    def feed(self, piece: bytes) -> Iterator[tuple[int, int, int, int, bytes]]:
        """The frames ``piece`` completes, in order."""
        buf = self._buf
        buf += piece
        unpack, size = HEADER.unpack_from, HEADER.size
        at, end = 0, len(buf)
        view = memoryview(buf)
        try:
            while end - at >= size:
                kind, tid, seq, t_ns, n = unpack(buf, at)
                if end - at - size < n:
                    break
                body = at + size
                yield kind, tid, seq, t_ns, bytes(view[body:body + n])
                at = body + n
        finally:
            view.release()
            del buf[:at]


__all__ = ["ABORT", "CLOSE", "CUSTOM", "HEADER", "LOST", "MAX_TOPICS", "MESSAGE", "TOPIC",
           "FrameReader", "pack_frame", "pack_json", "pack_messages"]
