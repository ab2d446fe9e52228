"""A vectorized rosbag2 MCAP writer: blocks of fixed-layout messages without per-message Python.

The per-sample topics of a simulation keep one CDR layout each (:mod:`dcsms_ros.cdr`), so a
block of K samples of T topics is one byte matrix: row i holds the T message records of sample
i side by side (each a 31-byte MCAP message header, then the CDR), built column-wise with
numpy. The rows are cut into chunks (zstd), each followed by its per-channel message indexes
(``(log_time, offset)`` pairs computed from the row layout, not message by message); the
summary (schemas, channels, chunk indexes, statistics, a ``rosbag2`` metadata record and its
index, summary offsets) and the footer close the file, and ``metadata.yaml`` is written as
rosbag2 (version 9) and rosbags write it, so ``ros2 bag info``, rosbags, the ``mcap`` library and
:mod:`.mcapchunks` read the bag. The bag is built in ``<out>.partial/`` and renamed to ``<out>``
only after a clean close (:mod:`.bagio`'s rule): there is never a bag without metadata.

Messages of one sample are written in topic order and samples in time order, and a single
message (mode, configuration) is placed among the rows at its sample, so every chunk is in log
time order (rosbags merges chunks assuming it).
"""

from __future__ import annotations

import shutil
import threading
import time
from array import array
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dcsms_ros import __version__
from dcsms_ros.analysis import staging
from dcsms_ros.analysis.mcapchunk import Chunk, ChunkBuffers
from dcsms_ros.analysis.mcaprecords import (
    MAGIC,
    MESSAGE,
    MESSAGE_HEADER,
    U16,
    RowTemplate,
    Topic,
    channel_index,
    map_field,
    record,
    rosbag2_metadata,
    statistics_record,
    string_field,
    write_metadata,
    write_summary,
)
from dcsms_ros.cdr import typestore
from dcsms_ros.errors import BagError

#: Uncompressed bytes per chunk (the reader holds one chunk at a time).
CHUNK_BYTES = 4 << 20
#: zstd level of the chunks (1: fast, ~4x smaller on the graph's streams).
ZSTD_LEVEL = 1
#: Age (s) at which a deferred-flush writer's :meth:`~McapBagWriter.flush` closes the open
#: chunk: a recorder killed before it closed its bag lost its last ~2 s (:mod:`.bagrecover`
#: reads the rest back), not its last 4 MB (a slow topic's whole recording).
CHUNK_MAX_AGE_S = 2.0
#: libyaml's safe dumper where PyYAML has it (the same text; a run's metadata 24 -> 6 ms).
_YAML: dict[str, Any] = {"Dumper": getattr(yaml, "CSafeDumper", yaml.SafeDumper),
                         "sort_keys": True}


class McapBagWriter:
    """Write a new rosbag2 MCAP bag ``out`` (a directory that must not exist).

    Parameters
    ----------
    out : str or Path
        The bag directory.
    chunk_bytes : int
        Uncompressed size at which a chunk is closed.
    compress : bool
        zstd chunks (default) or uncompressed.
    defer_flush : bool
        Leave full chunks for :meth:`flush` instead of compressing and writing them inside
        the :meth:`write` that filled them. A node's part recorder writes on its real-time hot
        thread, where closing a 4 MB chunk took 9-12 ms (a gap of 20+ samples at 2 kHz, every
        1.75 s, measured when the composed recorder wrote on its driver thread); the node's
        executor calls :meth:`flush` (:data:`CHUNK_MAX_AGE_S`). Such a writer also makes its
        chunk buffers at once (:class:`.mcapchunk.ChunkBuffers`): its writes fault no page.

    Attributes
    ----------
    counts : dict of str to int
        Messages written per topic.
    """

    def __init__(self, out: str | Path, chunk_bytes: int = CHUNK_BYTES,
                 compress: bool = True, defer_flush: bool = False) -> None:
        self.path = Path(out)
        self.defer_flush = defer_flush
        self.staging, self._inner = staging.claim(self.path)
        self.file = self._inner / f"{self.path.name}.mcap"
        self.chunk_bytes = chunk_bytes
        self._zstd: Any = None
        if compress:
            import zstandard  # noqa: PLC0415 - optional: only for compressed chunks

            self._zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
        self.topics: dict[str, Topic] = {}
        self._schemas: dict[str, tuple[int, bytes]] = {}
        self._buffers = ChunkBuffers(chunk_bytes, prefill=defer_flush)
        self._chunk = Chunk(self._buffers.take())
        #: what waits to go to the file, in file order: records (schemas, channels) and chunks
        self._pending: list[bytes | Chunk] = []
        self._chunk_indexes: list[bytes] = []
        self._t0, self._t1 = 2**63 - 1, 0
        #: rosbag2's ``custom_data`` of ``metadata.yaml`` (:meth:`set_custom_data`)
        self.custom_data: dict[str, str] = {}
        self._closed = False
        # a part recorder writes from its node's hot thread and flushes from its executor (a
        # recorder from its executor alone): every public call holds this lock, but only
        # for the in-memory state; the file is written under ``_flock`` (taken first, never
        # while ``_lock`` is held), so compressing a chunk never blocks a write
        self._lock = threading.RLock()
        self._flock = threading.RLock()
        try:
            self._inner.mkdir(parents=True)
            self._f = self.file.open("xb")
            self._f.write(MAGIC + record("header", string_field("ros2") + string_field(
                f"dcsms_ros-{__version__}")))
        except OSError as exc:
            shutil.rmtree(self.staging, ignore_errors=True)
            raise BagError(f"{self.path}: cannot create bag: {exc}") from None

    @property
    def counts(self) -> dict[str, int]:
        return {t.topic: t.count for t in self.topics.values()}

    # -- topics --------------------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, qos_yaml: str = "") -> None:
        """Register ``topic`` of ``msgtype`` (``pkg/msg/Name``); ``qos_yaml``: its offered QoS
        profiles as rosbag2 metadata YAML (e.g. :data:`.bagio.LATCHED_QOS`)."""
        with self._lock:
            self._add_topic(topic, msgtype, qos_yaml)
        self._flush_if_due()

    def _add_topic(self, topic: str, msgtype: str, qos_yaml: str) -> None:
        if topic in self.topics:
            raise BagError(f"{self.path}: topic {topic} added twice")
        if msgtype not in self._schemas:
            try:
                text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
            except Exception as exc:  # noqa: BLE001 - rosbags raises several types
                raise BagError(f"{self.path}: cannot add {topic} ({msgtype}): {exc}") from None
            sid = len(self._schemas) + 1
            rec = record("schema", U16.pack(sid) + string_field(msgtype) + string_field("ros2msg")
                          + string_field(text))
            self._schemas[msgtype] = (sid, rec)
            self._pending.append(rec)
        cid = len(self.topics) + 1
        t = Topic(topic, msgtype, cid, qos_yaml)
        self.topics[topic] = t
        self._pending.append(self._channel_record(t))

    def _channel_record(self, t: Topic) -> bytes:
        meta = map_field([(string_field("offered_qos_profiles"), string_field(t.qos_yaml))])
        return record("channel", U16.pack(t.channel) + U16.pack(self._schemas[t.msgtype][0])
                       + string_field(t.topic) + string_field("cdr") + meta)

    def set_custom_data(self, key: str, value: str) -> None:
        """One entry of the bag's ``custom_data`` (rosbag2 metadata), written at close."""
        with self._lock:
            self.custom_data[key] = value

    # -- messages ------------------------------------------------------------------------
    def write(self, topic: str, t_ns: int, data: bytes) -> None:
        """One message at log (and publish) time ``t_ns``. Raises :class:`BagError` after
        :meth:`close` (a write in another thread ends first) or for a topic not added."""
        self.write_all(((topic, t_ns, data),))

    def write_all(self, messages: Iterable[tuple[str, int, bytes]]) -> None:
        """Messages ``(topic, t_ns, data)`` in their order, under one hold of the lock (a
        recorder's batch: a node's part, the bag writer process's frames). Raises as
        :meth:`write`."""
        with self._lock:
            if self._closed:
                raise BagError(f"{self.path}: written after close")
            self._append(messages)
        self._flush_if_due()

    def _append(self, messages: Iterable[tuple[str, int, bytes]]) -> None:
        # a recorder's per-message path (~0.5 us): one loop, its state in locals, a struct packed
        # into the chunk's buffer, one copy, two index entries; the time range once per batch
        topics, limit, pack_into = self.topics, self.chunk_bytes, MESSAGE.pack_into
        ch = self._chunk
        buf, singles, t0, t1, size = ch.buf, ch.singles, ch.t0, ch.t1, ch.size
        room = len(buf)
        try:
            for topic, when, data in messages:
                t = topics.get(topic) or self._topic(topic)  # the latter raises
                t_ns = int(when)
                end = size + MESSAGE_HEADER + len(data)
                if end > room:
                    ch.size, ch.t0, ch.t1 = size, t0, t1
                    if size and end > limit:
                        self._close_chunk()
                        ch = self._chunk
                    buf = ch.reserve(MESSAGE_HEADER + len(data))
                    singles, t0, t1, size, room = ch.singles, ch.t0, ch.t1, ch.size, len(buf)
                    end = size + MESSAGE_HEADER + len(data)
                single = singles.get(t.channel)
                if single is None:
                    single = singles[t.channel] = array("Q")
                single.append(t_ns)
                single.append(size)
                pack_into(buf, size, 0x05, 22 + len(data), t.channel, 0, t_ns, t_ns)
                buf[size + MESSAGE_HEADER:end] = data
                size = end
                if t_ns < t0:  # noqa: PLR1730 - not min()/max(): two calls per message
                    t0 = t_ns
                if t_ns > t1:  # noqa: PLR1730
                    t1 = t_ns
                t.count += 1
        finally:  # what was appended before an error is in the chunk
            ch.size, ch.t0, ch.t1 = size, t0, t1

    def rows_template(self, topics: Sequence[str],
                      templates: Sequence[np.ndarray]) -> RowTemplate:
        """The byte template of one sample's records of ``topics`` (CDR ``templates[j]``
        (R_j,) uint8 each), for :meth:`write_encoded`."""
        return RowTemplate([self._topic(name) for name in topics], templates)

    def write_rows(self, t_ns: np.ndarray, topics: Sequence[str],
                   rows: Sequence[np.ndarray]) -> None:
        """K samples of several topics: ``rows[j]`` (K, R_j) uint8 is the CDR of ``topics[j]``
        for each sample, log time ``t_ns`` (K,) int64 (non-decreasing); sample by sample, the
        topics in the given order."""
        tpl = self.rows_template(topics, [r[0] if len(r) else np.zeros(r.shape[1], np.uint8)
                                          for r in rows])
        buf = tpl.encode(t_ns)
        for j, r in enumerate(rows):
            o = tpl.offsets[j] + MESSAGE_HEADER
            buf[:, o:o + r.shape[1]] = r
        self.write_encoded(t_ns, tpl, buf)

    def write_encoded(self, t_ns: np.ndarray, tpl: RowTemplate, buf: np.ndarray) -> None:
        """K samples already encoded by ``tpl`` (``buf`` (K, width) uint8, C-contiguous)."""
        t = np.ascontiguousarray(t_ns, dtype="<u8")
        k, w = buf.shape
        per_chunk = max(1, self.chunk_bytes // w)
        with self._lock:
            for tp in tpl.topics:
                tp.count += k
            for a in range(0, k, per_chunk):
                b = min(a + per_chunk, k)
                pos = np.arange(b - a, dtype=np.uint64) * np.uint64(w)
                index = {tp.channel: np.stack([t[a:b], pos + np.uint64(o)], axis=1)
                         for tp, o in zip(tpl.topics, tpl.offsets, strict=True)}
                rows: Any = buf[a:b]  # C-contiguous rows: no copy
                self._add(memoryview(rows).cast("B"), index, int(t[a]), int(t[b - 1]))
        self._flush_if_due()

    def write_records(self, t_ns: np.ndarray, channels: np.ndarray, records: np.ndarray,
                      starts: np.ndarray) -> None:
        """K message records already encoded (:func:`.mcaprecords.message_records`): record k
        is ``records[starts[k]:starts[k + 1]]``, log time ``t_ns[k]`` (non-decreasing), this
        writer's channel ``channels[k]``; cut into chunks as :meth:`write` cuts them."""
        t = np.ascontiguousarray(t_ns, dtype="<u8")
        with self._lock:
            by_channel = {tp.channel: tp for tp in self.topics.values()}
            for c, n in zip(*np.unique(channels, return_counts=True), strict=True):
                by_channel[int(c)].count += int(n)
            a = 0
            while a < t.size:  # what the open chunk still holds, else a chunk's worth
                room = self.chunk_bytes - self._chunk.size
                end = starts[a] + (room if room >= starts[a + 1] - starts[a] else self.chunk_bytes)
                b = min(max(int(np.searchsorted(starts, end, "right")) - 1, a + 1), t.size)
                piece: Any = records[starts[a]:starts[b]]  # contiguous: no copy
                self._add(memoryview(piece), channel_index(t[a:b], starts[a:b] - starts[a],
                                                           channels[a:b]), int(t[a]), int(t[b - 1]))
                a = b
        self._flush_if_due()

    def _topic(self, topic: str) -> Topic:
        try:
            return self.topics[topic]
        except KeyError:
            raise BagError(f"{self.path}: topic {topic} was not added") from None

    def _add(self, data: bytes | memoryview, index: dict[int, np.ndarray], t0: int,
             t1: int) -> None:
        """Append records to the open chunk (closed first if they would overflow it);
        ``index``: per channel (n, 2) uint64 [log time, offset of the record in ``data``]."""
        if self._chunk.size and self._chunk.size + len(data) > self.chunk_bytes:
            self._close_chunk()
        ch = self._chunk
        for c, entries in index.items():
            ch.move_singles(c)  # the channel's entries stay in record order
            e = entries.copy()
            e[:, 1] += np.uint64(ch.size)
            ch.index.setdefault(c, []).append(e)
        ch.put(data)
        ch.t0, ch.t1 = min(ch.t0, t0), max(ch.t1, t1)

    def _close_chunk(self) -> None:
        """Queue the open chunk for :meth:`flush` and open a new one (under ``_lock``)."""
        ch = self._chunk
        if not ch.size:
            return
        for c in list(ch.singles):
            ch.move_singles(c)
        self._pending.append(ch)
        self._chunk = Chunk(self._buffers.take())

    def _flush_if_due(self) -> None:
        if self._pending and not self.defer_flush:
            self.flush()

    def flush(self) -> None:
        """Write what is queued: full chunks (compressed here) and new topics' records; the
        open chunk stays open (with ``defer_flush``, until it is :data:`CHUNK_MAX_AGE_S` old).
        Safe beside :meth:`write` in another thread, which it blocks only to take the queue.

        Raises
        ------
        BagError
            The file cannot be written (the bag is then aborted).
        """
        with self._flock:
            with self._lock:
                if self.defer_flush and time.monotonic() - self._chunk.born >= CHUNK_MAX_AGE_S:
                    self._close_chunk()  # an empty one stays open
                items, self._pending = self._pending, []
            self._emit(items)

    def _emit(self, items: list[bytes | Chunk]) -> None:
        """Write ``items`` in order (under ``_flock``)."""
        try:
            for item in items:
                if isinstance(item, Chunk):
                    self._write_chunk(item)
                else:
                    self._f.write(item)
            if items and self.defer_flush:  # in the file, not in this process's buffer
                self._f.flush()
        except OSError as exc:
            self.abort()
            raise BagError(f"{self.path}: cannot write bag: {exc}") from None

    def _write_chunk(self, ch: Chunk) -> None:
        """Write chunk ``ch`` and its message indexes; remember its chunk index (under
        ``_flock``)."""
        self._chunk_indexes.append(ch.write(self._f, self._zstd))
        self._t0, self._t1 = min(self._t0, ch.t0), max(self._t1, ch.t1)
        self._buffers.give(ch.buf)

    # -- closing -------------------------------------------------------------------------
    def close(self) -> Path:
        """Finish the file (summary, footer) and ``metadata.yaml``; move the bag into place."""
        with self._flock:
            with self._lock:
                if self._closed:
                    return self.path
                self._close_chunk()
                self._closed = True  # a write from now on raises: nothing is left behind
                items, self._pending = self._pending, []
            self._emit(items)
            return self._close()

    def _close(self) -> Path:
        try:
            topics = list(self.topics.values())
            meta = rosbag2_metadata(self.file.name, topics, self._t0, self._t1, self.custom_data)
            text = yaml.dump(meta["rosbag2_bagfile_information"], **_YAML)
            f = self._f
            meta_index = write_metadata(f, text)
            write_summary(f, [
                ("schema", [r for _, r in self._schemas.values()]),
                ("channel", [self._channel_record(t) for t in self.topics.values()]),
                ("chunk_index", self._chunk_indexes),
                ("metadata_index", [meta_index]),
                ("statistics", [statistics_record(topics, len(self._schemas),
                                                  len(self._chunk_indexes), self._t0,
                                                  self._t1)])])
            f.close()
            (self._inner / "metadata.yaml").write_text(yaml.dump(meta, **_YAML))
        except OSError as exc:
            self.abort()
            raise BagError(f"{self.path}: cannot finish bag: {exc}") from None
        return staging.publish(self.path, self.staging, self._inner)

    def abort(self) -> None:
        """Give up: close the file and remove the staging directory."""
        with self._flock, self._lock:
            self._closed = True
            self._pending.clear()
            try:
                self._f.close()
            except OSError:
                pass
            shutil.rmtree(self.staging, ignore_errors=True)


__all__ = ["CHUNK_BYTES", "CHUNK_MAX_AGE_S", "McapBagWriter"]
