"""The MCAP records a rosbag2 bag is made of: opcodes, strings, maps, message headers, and
:class:`RowTemplate`, one sample's message records of several topics side by side (used by
:class:`.mcapwrite.McapBagWriter` and the streamed batch bags of :mod:`.stream`)."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

MAGIC = b"\x89MCAP0\r\n"
#: Record opcodes of the MCAP format.
OPCODES = {"header": 0x01, "footer": 0x02, "schema": 0x03, "channel": 0x04, "message": 0x05,
       "chunk": 0x06, "message_index": 0x07, "chunk_index": 0x08, "statistics": 0x0B,
       "metadata": 0x0C, "metadata_index": 0x0D, "summary_offset": 0x0E, "data_end": 0x0F}
#: Message record header: opcode, length, channel id, sequence, log time, publish time.
MESSAGE_HEADER = 31
U16, U32, U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
#: A message record's header: opcode, record length, channel, sequence, log and publish time.
MESSAGE = struct.Struct("<BQHIQQ")


def string_field(text: str) -> bytes:
    """An MCAP string: length-prefixed UTF-8."""
    raw = text.encode()
    return U32.pack(len(raw)) + raw


def record(op: str, body: bytes) -> bytes:
    """One MCAP record: opcode, body length, body."""
    return bytes([OPCODES[op]]) + U64.pack(len(body)) + body


def map_field(pairs: Sequence[tuple[bytes, bytes]]) -> bytes:
    """An MCAP map of already encoded keys and values: byte length, then the pairs."""
    body = b"".join(k + v for k, v in pairs)
    return U32.pack(len(body)) + body


@dataclass
class Topic:
    """A channel of the bag being written and how many messages it has."""

    topic: str
    msgtype: str
    channel: int
    qos_yaml: str
    count: int = 0


class RowTemplate:
    """One sample's message records of several topics side by side: the bytes that do not
    change from sample to sample, and where the times go.

    Attributes
    ----------
    width : int
        Bytes per sample.
    offsets : list of int
        Start of each topic's record in a row (its CDR starts :data:`MESSAGE_HEADER` later).
    """

    def __init__(self, topics: Sequence[Topic], templates: Sequence[np.ndarray]) -> None:
        self.topics = list(topics)
        parts, self.offsets = [], []
        at = 0
        for tp, cdr in zip(self.topics, templates, strict=True):
            n = int(np.asarray(cdr).size)
            parts.append(np.frombuffer(bytes([OPCODES["message"]]) + U64.pack(22 + n)
                                       + U16.pack(tp.channel) + U32.pack(0) + bytes(16),
                                       np.uint8))
            parts.append(np.asarray(cdr, np.uint8))
            self.offsets.append(at)
            at += MESSAGE_HEADER + n
        self.row = np.concatenate(parts)
        self.width = at

    def encode(self, t_ns: np.ndarray) -> np.ndarray:
        """(K, width) rows: the template with the log and publish times of ``t_ns`` (K,);
        the caller writes each message's own fields at ``offsets[j] + MESSAGE_HEADER + ...``."""
        t = np.ascontiguousarray(t_ns, dtype="<u8")
        k = t.size
        # bytearray repetition is one memcpy per row: ~10x a numpy broadcast of uint8 rows
        buf = np.frombuffer(bytearray(self.row.tobytes()) * k, np.uint8).reshape(k, self.width)
        tb = np.repeat(t[:, None], 2, axis=1).view(np.uint8)  # log and publish time
        for o in self.offsets:
            buf[:, o + 15:o + 31] = tb
        return buf

__all__ = ["MAGIC", "MESSAGE", "MESSAGE_HEADER", "OPCODES", "U16", "U32", "U64", "RowTemplate",
           "Topic", "map_field", "record", "string_field"]
