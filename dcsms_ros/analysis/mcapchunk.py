"""One MCAP chunk of :class:`.mcapwrite.McapBagWriter`: its records as they are filled, and how
it goes to the file (chunk record, then one message index per channel)."""

from __future__ import annotations

import time
import zlib
from array import array
from typing import IO, Any

import numpy as np

from dcsms_ros.analysis.mcaprecords import OPCODES, U16, U32, U64, map_field, record, string_field


class Chunk:
    """Records of the chunk being filled: their bytes and per-channel index entries.

    The bytes are written into ``buf`` from its start, ``size`` of them used, and single
    messages' index entries go into an ``array('Q')``: closing a chunk then needs no
    ``bytes.join`` over tens of thousands of parts and no list-to-array conversion, the two
    steps that hold the GIL (3 ms each on a 4 MB chunk of the graph's streams); compression
    and the CRC release it. ``buf`` grows only when it is short (:meth:`reserve`), so a buffer
    kept from a written chunk (:class:`.mcapwrite.McapBagWriter`) takes the next one's records
    without a new allocation: a growing ``bytearray`` was copied into new memory, and its
    first touch of those pages faulted 88-760 times in one write, at ~9 us a fault on this
    virtual machine (0.4-7.3 ms in a node's real-time hot thread; docs/performance.md,
    fifty-eighth session).

    Parameters
    ----------
    buf : bytearray
        The buffer to fill (its contents are overwritten).
    """

    def __init__(self, buf: bytearray) -> None:
        self.buf = buf
        #: bytes of ``buf`` used
        self.size = 0
        self.index: dict[int, list[np.ndarray]] = {}
        #: per channel, the [log time, offset] pairs of single messages not yet in ``index``
        self.singles: dict[int, array[int]] = {}
        self.t0 = 2**63 - 1
        self.t1 = 0
        #: when the chunk was opened (``time.monotonic``, s)
        self.born = time.monotonic()

    @property
    def data(self) -> memoryview:
        """The records so far (a view of ``buf``)."""
        return memoryview(self.buf)[:self.size]

    def reserve(self, n: int) -> bytearray:
        """Room for ``n`` more bytes: a buffer twice as large (or more), the records copied,
        if ``buf`` is short. Returns ``buf``."""
        if self.size + n > len(self.buf):
            grown = bytearray(max(2 * len(self.buf), self.size + n))
            grown[:self.size] = self.data
            self.buf = grown
        return self.buf

    def put(self, data: bytes | memoryview) -> None:
        """Append ``data`` (whole records)."""
        end = self.size + len(data)
        self.reserve(len(data))[self.size:end] = data
        self.size = end

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


class ChunkBuffers:
    """The buffers of one writer's chunks: a written chunk's buffer is kept for a later chunk
    (up to :data:`SPARE`), so a writer that runs long allocates and touches no new memory.

    Parameters
    ----------
    size : int
        A full chunk, bytes.
    prefill : bool
        Make :data:`SPARE` full-size buffers now, their pages touched (a writer on a real-time
        thread: its writes then fault no page, :class:`Chunk`); else a new buffer starts at
        :data:`FIRST_BYTES` and doubles as needed, so a short bag touches no more memory than
        it holds.
    """

    #: Written chunks' buffers kept for later chunks.
    SPARE = 2
    #: First size of a new buffer without ``prefill``, bytes.
    FIRST_BYTES = 64 << 10

    def __init__(self, size: int, prefill: bool) -> None:
        self._first = size if prefill else min(self.FIRST_BYTES, size)
        self._spare = [bytearray(size) for _ in range(self.SPARE)] if prefill else []

    def take(self) -> bytearray:
        """A buffer for a new chunk: a written chunk's, else a new one. From one thread at a
        time (the writer's lock)."""
        return self._spare.pop() if self._spare else bytearray(self._first)

    def give(self, buf: bytearray) -> None:
        """``buf``'s chunk is written: keep it for a later chunk, if fewer than
        :data:`SPARE` are kept (a list's append: safe beside :meth:`take` in another
        thread)."""
        if len(self._spare) < self.SPARE:
            self._spare.append(buf)


__all__ = ["Chunk", "ChunkBuffers"]
