"""The MCAP records a rosbag2 bag is made of: opcodes, strings, maps, message headers,
:class:`RowTemplate` (one sample's message records of several topics side by side), message
records in bulk, the statistics record and the rosbag2 metadata (used by
:class:`.mcapwrite.McapBagWriter`, the streamed batch bags of :mod:`.stream` and the merge of
:mod:`.bagmerge`)."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, BinaryIO

import numpy as np
import yaml

from dcsms_ros.cdr import typestore

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
#: The same header as a numpy record (packed: :data:`MESSAGE_HEADER` bytes).
MESSAGE_DTYPE = np.dtype([("op", "u1"), ("length", "<u8"), ("channel", "<u2"),
                          ("sequence", "<u4"), ("log", "<u8"), ("publish", "<u8")])


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

def rosbag2_metadata(file_name: str, topics: Sequence[Topic], t0: int, t1: int,
                     custom_data: dict[str, str]) -> dict[str, Any]:
    """The rosbag2 metadata (version 9) of a one-file MCAP bag whose messages span log times
    ``t0``-``t1`` (ns): written as the file's ``rosbag2`` metadata record and as
    ``metadata.yaml``."""
    n = sum(t.count for t in topics)
    start = t0 if n else 0
    dur = max(0, t1 - t0) if n else 0
    return {"rosbag2_bagfile_information": {
        "version": 9, "storage_identifier": "mcap", "relative_file_paths": [file_name],
        "duration": {"nanoseconds": dur}, "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": n,
        "topics_with_message_count": [
            {"topic_metadata": {
                "name": t.topic, "type": t.msgtype, "serialization_format": "cdr",
                "offered_qos_profiles": yaml.safe_load(t.qos_yaml) if t.qos_yaml else [],
                "type_description_hash": typestore().hash_rihs01(t.msgtype)},
             "message_count": t.count} for t in topics],
        "compression_format": "", "compression_mode": "",
        "files": [{"path": file_name, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": dur}, "message_count": n}],
        "custom_data": dict(custom_data) or None, "ros_distro": "rosbags"}}


def statistics_record(topics: Sequence[Topic], schemas: int, chunks: int, t0: int,
                      t1: int) -> bytes:
    """The file's statistics record: messages in all and per channel, counts, time span."""
    counts = [(t.channel, t.count) for t in topics]
    n = sum(c for _, c in counts)
    return record("statistics", U64.pack(n) + U16.pack(schemas) + U32.pack(len(topics))
                  + U32.pack(0) + U32.pack(1) + U32.pack(chunks)
                  + U64.pack(t0 if n else 0) + U64.pack(t1 if n else 0)
                  + map_field([(U16.pack(c), U64.pack(k)) for c, k in counts]))


def channel_index(t_ns: np.ndarray, offsets: np.ndarray,
                  channels: np.ndarray) -> dict[int, np.ndarray]:
    """Per channel, the ``(log time, offset)`` uint64 pairs of its messages (a chunk's message
    index entries, in the given order)."""
    t, off = np.asarray(t_ns, "<u8"), np.asarray(offsets).astype("<u8")
    return {int(c): np.stack([t[channels == c], off[channels == c]], axis=1)
            for c in np.unique(channels)}


def copy_ranges(dst: np.ndarray, dst_at: np.ndarray, src: np.ndarray, src_at: np.ndarray,
                lengths: np.ndarray) -> None:
    """``dst[dst_at[k]:dst_at[k] + lengths[k]] = src[src_at[k]:src_at[k] + lengths[k]]`` for
    every k, without per-range Python: one 2-D gather per distinct length (the graph's topics
    keep one size each), or, where most lengths differ, one index per byte."""
    sizes = np.unique(lengths)
    if sizes.size <= max(8, lengths.size // 64):
        for n in sizes.tolist():
            m = lengths == n
            r = np.arange(n)
            dst[dst_at[m][:, None] + r] = src[src_at[m][:, None] + r]
        return
    within = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    dst[np.repeat(dst_at, lengths) + within] = src[np.repeat(src_at, lengths) + within]


def message_records(t_ns: np.ndarray, channels: np.ndarray, payload: np.ndarray,
                    offsets: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """K message records in one buffer, without per-message Python.

    Parameters
    ----------
    t_ns : ndarray of int64, shape (K,)
        Log (and publish) time of each message, ns.
    channels : ndarray of int, shape (K,)
        Channel id of each message.
    payload : ndarray of uint8
        Bytes holding every message's CDR: message k is ``payload[offsets[k]:offsets[k] +
        lengths[k]]``.
    offsets, lengths : ndarray of int64, shape (K,)

    Returns
    -------
    records : ndarray of uint8
        The K records back to back.
    starts : ndarray of int64, shape (K + 1,)
        Where each record starts in ``records``; the last entry is its length.
    """
    lengths = np.asarray(lengths, np.int64)
    k = lengths.size
    starts = np.zeros(k + 1, np.int64)
    np.cumsum(lengths + MESSAGE_HEADER, out=starts[1:])
    out = np.empty(int(starts[-1]), np.uint8)
    head = np.zeros(k, MESSAGE_DTYPE)
    head["op"] = OPCODES["message"]
    head["length"] = lengths + (MESSAGE_HEADER - 9)  # the record's length after its opcode
    head["channel"] = channels
    head["log"] = head["publish"] = t_ns
    out[starts[:-1, None] + np.arange(MESSAGE_HEADER)] = head.view(np.uint8).reshape(
        k, MESSAGE_HEADER)
    copy_ranges(out, starts[:-1] + MESSAGE_HEADER, payload, np.asarray(offsets, np.int64),
                lengths)
    return out, starts


def write_metadata(f: BinaryIO, text: str) -> bytes:
    """Write rosbag2's ``metadata`` record holding ``text`` (its serialized metadata YAML) to
    ``f``; returns the record's ``metadata_index`` record for the summary."""
    start = f.tell()
    f.write(record("metadata", string_field("rosbag2") + map_field(
        [(string_field("serialized_metadata"), string_field(text.strip()))])))
    return record("metadata_index", U64.pack(start) + U64.pack(f.tell() - start)
                  + string_field("rosbag2"))


def write_summary(f: BinaryIO, sections: Sequence[tuple[str, Sequence[bytes]]]) -> None:
    """End the data section of file ``f`` and write the summary: each section's records
    (``(opcode name, records)``, in file order), a summary offset per non-empty section and
    the footer with the magic."""
    f.write(record("data_end", U32.pack(0)))
    groups = []
    summary_start = f.tell()
    for op, recs in sections:
        at = f.tell()
        f.writelines(recs)
        if recs:
            groups.append((op, at, f.tell() - at))
    offsets_start = f.tell()
    for op, at, length in groups:
        f.write(record("summary_offset", bytes([OPCODES[op]]) + U64.pack(at) + U64.pack(length)))
    f.write(record("footer", U64.pack(summary_start) + U64.pack(offsets_start) + U32.pack(0))
            + MAGIC)


__all__ = ["MAGIC", "MESSAGE", "MESSAGE_DTYPE", "MESSAGE_HEADER", "OPCODES", "U16", "U32", "U64",
           "RowTemplate", "Topic", "channel_index", "copy_ranges", "map_field", "message_records",
           "record", "rosbag2_metadata", "statistics_record", "string_field", "write_metadata",
           "write_summary"]
