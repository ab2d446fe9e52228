"""Read chosen MCAP channels chunk by chunk as byte matrices, without per-message Python.

A rosbag2 MCAP file (rosbags, ``ros2 bag record``) is indexed: its summary lists every chunk
with the file offsets of the chunk's per-channel message indexes, each a packed array of
``(log_time u64, offset u64)``. One chunk is read (and decompressed) at a time, the wanted
channels' offsets come from ``np.frombuffer`` over their indexes, and the message payloads are
gathered with one fancy index into a ``(K, R)`` uint8 matrix when every message of the channel
in that chunk has the same size (the fixed-layout topics of the graph), else into a list of
bytes. Messages come out per channel in the order rosbags yields them: chunk by chunk in file
order, inside a chunk by log time (stable over file offset).

Memory: one chunk (rosbag2 default ~1 MB) plus its matrices. An unindexed or unusual file
raises :class:`Unsupported` and the caller uses the rosbags reader instead.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader

_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_MESSAGE = 0x06, 0x07, 0x05
#: opcode (1) + record length (8) + channel id (2) + sequence (4) + log and publish time (16)
_MESSAGE_HEADER = 31
_INDEX_ENTRY = np.dtype([("t", "<u8"), ("off", "<u8")])


class Unsupported(Exception):
    """The file cannot be read by this module (no summary, unknown compression ...)."""


@dataclass
class Block:
    """Messages of one channel from one chunk.

    Attributes
    ----------
    channel : int
        MCAP channel id.
    log_ns : ndarray of int64, shape (K,)
        Log (receive) times.
    rows : ndarray of uint8, shape (K, R) or None
        Payloads (CDR with encapsulation header) when all K have the same size R.
    buffers : list of bytes or None
        Payloads otherwise.
    offsets : ndarray of int64, shape (K,) or None
        Each message record's offset in the uncompressed chunk (the order messages of
        several channels were written in).
    """

    channel: int
    log_ns: np.ndarray
    rows: np.ndarray | None = None
    buffers: list[bytes] | None = None
    offsets: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.log_ns.size)


def summary(path: Path,
            empty_ok: bool = False) -> tuple[dict[int, tuple[str, str]], list[Any]]:
    """Channels ``{id: (topic, schema name)}`` and chunk indexes (file order) of one file;
    ``empty_ok``: a file whose statistics count no message has no chunk (not an error).

    Raises
    ------
    Unsupported
        If the file has no summary with chunk indexes.
    """
    with open(path, "rb") as f:
        try:
            s = make_reader(f).get_summary()
        except Exception as exc:  # noqa: BLE001 - the mcap library raises many types
            raise Unsupported(f"{path}: no readable summary: {exc}") from None
    empty = (empty_ok and s is not None and s.statistics is not None
             and s.statistics.message_count == 0)
    if s is None or not (s.chunk_indexes or empty):
        raise Unsupported(f"{path}: no chunk index")
    chans = {cid: (c.topic, s.schemas[c.schema_id].name if c.schema_id in s.schemas else "")
             for cid, c in s.channels.items()}
    return chans, sorted(s.chunk_indexes, key=lambda c: c.chunk_start_offset)


def _decompress(data: memoryview, compression: str, size: int) -> bytes | memoryview:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard  # noqa: PLC0415 - optional: only for compressed chunks

        return zstandard.ZstdDecompressor().decompress(bytes(data), max_output_size=size)
    if compression == "lz4":
        import lz4.frame  # type: ignore[import-untyped]  # noqa: PLC0415 - optional, as above

        return bytes(lz4.frame.decompress(bytes(data)))
    raise Unsupported(f"unknown chunk compression {compression!r}")


def _records(buf: bytes, ci: Any) -> np.ndarray:
    """The uncompressed records of the chunk at the start of ``buf`` as uint8, CRC checked."""
    if buf[0] != _OP_CHUNK:
        raise ValueError(f"no chunk record at offset {ci.chunk_start_offset}")
    crc = int.from_bytes(buf[33:37], "little")
    start = 9 + 40 + len(ci.compression)
    view = memoryview(buf)[start:start + ci.compressed_size]
    if len(view) != ci.compressed_size:
        raise ValueError("truncated chunk")
    raw = _decompress(view, ci.compression, ci.uncompressed_size)
    if len(raw) != ci.uncompressed_size:
        raise ValueError("chunk size mismatch")
    if crc and zlib.crc32(raw) != crc:
        raise ValueError(f"chunk checksum mismatch at offset {ci.chunk_start_offset}")
    return np.frombuffer(raw, np.uint8)


def _index(buf: bytes, pos: int) -> np.ndarray:
    if buf[pos] != _OP_MESSAGE_INDEX:
        raise ValueError("no message index record where the summary points")
    n = int.from_bytes(buf[pos + 11:pos + 15], "little") // _INDEX_ENTRY.itemsize
    return np.frombuffer(buf, _INDEX_ENTRY, count=n, offset=pos + 15)


def _gather(rec: np.ndarray, start: np.ndarray, width: int) -> np.ndarray:
    """Rows ``rec[start[i]:start[i] + width]`` as a (K, width) matrix: a strided view when the
    starts are evenly spaced (topics interleaved regularly), else one fancy-index copy."""
    if start.size > 1:
        step = int(start[1] - start[0])
        if step >= width and np.all(np.diff(start) == step):
            return np.lib.stride_tricks.as_strided(rec[int(start[0]):], (start.size, width),
                                                   (step, 1), writeable=False)
    return rec[start[:, None] + np.arange(width)]


def _block(cid: int, rec: np.ndarray, entries: np.ndarray) -> Block:
    t = entries["t"].astype(np.int64)
    off = entries["off"].astype(np.int64)
    if np.any(np.diff(t) < 0) or np.any(np.diff(off) < 0):
        order = np.lexsort((off, t))
        t, off = t[order], off[order]
    if off.size and (off[-1] + _MESSAGE_HEADER > rec.size or np.any(rec[off] != _OP_MESSAGE)):
        raise ValueError("message index points outside the chunk's message records")
    lengths = _gather(rec, off + 1, 8).view("<u8")[:, 0].astype(np.int64) - 22
    start = off + _MESSAGE_HEADER
    if off.size and np.any(start + lengths > rec.size):
        raise ValueError("message runs past the end of its chunk")
    if lengths.size and np.all(lengths == lengths[0]):
        rows = _gather(rec, start, int(lengths[0]))
        return Block(cid, t, rows=rows, offsets=off)
    bufs = [rec[s:s + n].tobytes() for s, n in zip(start.tolist(), lengths.tolist(),
                                                      strict=True)]
    return Block(cid, t, buffers=bufs, offsets=off)


def iter_blocks(path: Path, channels: set[int], chunks: list[Any],
                progress: Callable[[int], None] | None = None) -> Iterator[Block]:
    """Yield, chunk by chunk in file order, one :class:`Block` per wanted channel present.

    Parameters
    ----------
    path : Path
        The .mcap file; ``chunks`` its chunk indexes from :func:`summary`.
    channels : set of int
        Channel ids to read.
    progress : callable(messages), optional
        Called after each chunk with the number of wanted messages it held.

    Raises
    ------
    ValueError
        If the file is truncated or inconsistent with its summary.
    """
    with open(path, "rb") as f:
        for ci in chunks:
            ids = [c for c in ci.message_index_offsets if c in channels]
            if not ids:
                continue
            f.seek(ci.chunk_start_offset)
            buf = f.read(ci.chunk_length + ci.message_index_length)
            if len(buf) != ci.chunk_length + ci.message_index_length:
                raise ValueError(f"truncated at chunk offset {ci.chunk_start_offset}")
            rec = _records(buf, ci)
            n = 0
            for cid in ids:
                block = _block(cid, rec, _index(buf, ci.message_index_offsets[cid]
                                                - ci.chunk_start_offset))
                n += len(block)
                yield block
            if progress is not None:
                progress(n)


__all__ = ["Block", "Unsupported", "iter_blocks", "summary"]
