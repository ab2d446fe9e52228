"""One MCAP chunk of :class:`.mcapwrite.McapBagWriter`: its records as they are filled, and how
it goes to the file (chunk record, then one message index per channel)."""

from __future__ import annotations

import time
import zlib
from array import array
from dataclasses import dataclass, field
from typing import IO, Any

import numpy as np

from dcsms_ros.analysis.mcaprecords import OPCODES, U16, U32, U64, map_field, record, string_field


@dataclass
class Chunk:
    """Records of the chunk being filled: their bytes and per-channel index entries.

    The bytes grow in one ``bytearray`` and single messages' index entries in an
    ``array('Q')``: closing a chunk then needs no ``bytes.join`` over tens of thousands of
    parts and no list-to-array conversion, the two steps that hold the GIL (3 ms each on a
    4 MB chunk of the graph's streams); compression and the CRC release it.
    """

    data: bytearray = field(default_factory=bytearray)
    index: dict[int, list[np.ndarray]] = field(default_factory=dict)
    #: per channel, the [log time, offset] pairs of single messages not yet in ``index``
    singles: dict[int, array[int]] = field(default_factory=dict)
    t0: int = 2**63 - 1
    t1: int = 0
    #: when the chunk was opened (``time.monotonic``, s)
    born: float = field(default_factory=time.monotonic)

    @property
    def size(self) -> int:
        return len(self.data)

    def move_singles(self, c: int) -> None:
        """Move channel ``c``'s single-message entries into the index arrays."""
        single = self.singles.pop(c, None)
        if single:  # a view of the array, which takes no more entries
            self.index.setdefault(c, []).append(np.frombuffer(single, np.uint64).reshape(-1, 2))

    def write(self, f: IO[bytes], zstd: Any) -> bytes:
        """Write the chunk (zstd-compressed with ``zstd``, a compressor, or stored) and its
        message indexes to ``f``; returns its chunk index record for the summary."""
        raw = self.data
        crc = zlib.crc32(raw)
        comp, name = (zstd.compress(raw), "zstd") if zstd is not None else (raw, "")
        start = f.tell()
        body = (U64.pack(self.t0) + U64.pack(self.t1) + U64.pack(len(raw)) + U32.pack(crc)
                + string_field(name) + U64.pack(len(comp)))
        # the record's opcode and length, then its body in two writes: no copy of the chunk
        f.write(bytes([OPCODES["chunk"]]) + U64.pack(len(body) + len(comp)) + body)
        f.write(comp)
        end = f.tell()
        offsets = []
        for c in sorted(self.index):
            e = np.concatenate(self.index[c]).astype("<u8")
            offsets.append((c, f.tell()))
            f.write(record("message_index", U16.pack(c) + U32.pack(e.nbytes) + e.tobytes()))
        return record("chunk_index", U64.pack(self.t0) + U64.pack(self.t1) + U64.pack(start)
                      + U64.pack(end - start)
                      + map_field([(U16.pack(c), U64.pack(o)) for c, o in offsets])
                      + U64.pack(f.tell() - end) + string_field(name) + U64.pack(len(comp))
                      + U64.pack(len(raw)))


__all__ = ["Chunk"]
