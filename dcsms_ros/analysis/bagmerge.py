"""Merge bags of disjoint topics into one bag, messages in log-time order (no rclpy).

``dcsms up --record`` of one process per node writes one bag per node process (the per-sample
topics it publishes, :mod:`dcsms_ros.nodes.recorder_part`) and one of its recorder process
(every other topic); :func:`merge_bags` makes them the one bag the user asked for. Messages
keep their bytes and log times, topics their types and offered QoS profiles, and the
recorders' published counts (``custom_data``) are joined, so the merged bag reads as if one
recorder had written it.

The merge runs at the end of every recorded per-process run, so it goes chunk by chunk, without
per-message Python (:mod:`.mcapchunks` in, :func:`.mcaprecords.message_records` out): the
inputs' chunks are read in the order of their first log time, and what was read is written up
to the first log time of the next chunk to read, which nothing unread can precede. Ties keep
the inputs' order, then each input's own. Memory: a few chunks. Messages per second: see
docs/performance.md ("The merge of a per-process recording"). An input that is not an indexed
MCAP file (a SQLite bag) is merged message by message through rosbags.
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.rosbag2 import Reader, ReaderError

from dcsms_ros.analysis.gaps import PUBLISHED_KEY, read_published
from dcsms_ros.analysis.mcapchunks import Block, Unsupported, iter_blocks, summary
from dcsms_ros.analysis.mcaprecords import copy_ranges, message_records
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.errors import BagError

#: libyaml's safe loader where PyYAML has it (~7x faster on a part's metadata).
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _info(bag: Path) -> dict[str, Any]:
    """A closed bag's ``metadata.yaml`` information."""
    try:
        meta = yaml.load((bag / "metadata.yaml").read_text(), Loader=_LOADER)
        info = meta["rosbag2_bagfile_information"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        raise BagError(f"{bag}: not a closed bag (no readable metadata.yaml)") from None
    if not isinstance(info, dict):
        raise BagError(f"{bag}: not a closed bag (no readable metadata.yaml)")
    return info


@dataclass
class _Source:
    """One input read chunk-wise: its MCAP file, its channels as the output's, its chunks."""

    file: Path
    channels: dict[int, int]
    chunks: list[Any]


def _sources(inputs: Sequence[Path], infos: Sequence[dict[str, Any]],
             out_channel: dict[str, int]) -> list[_Source] | None:
    """Each input as a :class:`_Source`, or None if one is not a single indexed MCAP file."""
    sources = []
    for bag, info in zip(inputs, infos, strict=True):
        files = info.get("relative_file_paths") or []
        if info.get("storage_identifier") != "mcap" or len(files) != 1:
            return None
        try:
            chans, chunks = summary(bag / files[0], empty_ok=True)
        except (Unsupported, OSError):
            return None
        sources.append(_Source(bag / files[0], {cid: out_channel[topic] for cid, (topic, _)
                                                 in chans.items() if topic in out_channel},
                               chunks))
    return sources


class _Pool:
    """Messages read and not yet written: log times, output channels, sort keys (input,
    chunk, record offset) and their bytes."""

    def __init__(self) -> None:
        self.payload = np.zeros(0, np.uint8)
        self.cols: dict[str, np.ndarray] = {k: np.zeros(0, np.int64) for k in
                                            ("t", "channel", "input", "chunk", "offset", "at",
                                             "length")}

    def add(self, blocks: Sequence[tuple[Block, int]], source: int, chunk: int) -> None:
        """Append the ``blocks`` of chunk ``chunk`` of input ``source``, each with its channel
        in the output."""
        parts: list[np.ndarray] = [self.payload]
        new: dict[str, list[np.ndarray]] = {n: [c] for n, c in self.cols.items()}
        size = self.payload.size
        for block, channel in blocks:
            k = len(block)
            if block.rows is not None:
                data = np.ascontiguousarray(block.rows).reshape(-1)
                lengths = np.full(k, block.rows.shape[1], np.int64)
            else:
                bufs = block.buffers or []
                data = np.frombuffer(b"".join(bufs), np.uint8)
                lengths = np.fromiter(map(len, bufs), np.int64, k)
            parts.append(data)
            cols = {"t": block.log_ns, "channel": np.full(k, channel),
                    "input": np.full(k, source), "chunk": np.full(k, chunk),
                    "offset": block.offsets if block.offsets is not None else np.arange(k),
                    "at": size + _exclusive_cumsum(lengths), "length": lengths}
            for n, col in cols.items():
                new[n].append(np.asarray(col, np.int64))
            size += data.size
        self.payload = np.concatenate(parts)
        self.cols = {n: np.concatenate(cs) for n, cs in new.items()}

    def write_before(self, writer: McapBagWriter, t_end: float) -> None:
        """Write the messages logged before ``t_end`` (ns) in order; keep the rest (their
        bytes are moved only once they are at most half of what is held: amortized, each
        byte once)."""
        c = self.cols
        order = np.lexsort((c["offset"], c["chunk"], c["input"], c["t"]))
        n = int(np.searchsorted(c["t"][order], t_end, "left")) if np.isfinite(t_end) \
            else order.size
        if n:
            now = order[:n]
            records, starts = message_records(c["t"][now], c["channel"][now], self.payload,
                                              c["at"][now], c["length"][now])
            writer.write_records(c["t"][now], c["channel"][now], records, starts)
        rest = order[n:]
        self.cols = {name: col[rest] for name, col in c.items()}
        live = int(self.cols["length"].sum())
        if self.payload.size > 2 * live:  # mostly written: the rest's bytes to the front
            at = _exclusive_cumsum(self.cols["length"])
            payload = np.empty(live, np.uint8)
            copy_ranges(payload, at, self.payload, self.cols["at"], self.cols["length"])
            self.payload, self.cols["at"] = payload, at


def _exclusive_cumsum(x: np.ndarray) -> np.ndarray:
    """``[0, x0, x0 + x1, ...]`` without the total (int64)."""
    out = np.zeros(x.size, np.int64)
    np.cumsum(x[:-1], out=out[1:])
    return out


def _merge_chunks(sources: Sequence[_Source], writer: McapBagWriter) -> None:
    """Every message of ``sources`` into ``writer``, chunk by chunk (see the module notes)."""
    queue = [(ci.message_start_time, i, j, ci) for i, s in enumerate(sources)
             for j, ci in enumerate(s.chunks)]
    heapq.heapify(queue)
    pool = _Pool()
    while queue:
        _, i, j, ci = heapq.heappop(queue)
        src = sources[i]
        try:
            pool.add([(b, src.channels[b.channel]) for b in
                      iter_blocks(src.file, set(src.channels), [ci])], i, j)
        except (ValueError, Unsupported, OSError) as exc:
            raise BagError(f"cannot merge {src.file}: {exc}") from None
        pool.write_before(writer, queue[0][0] if queue else np.inf)


def _messages(bag: Path) -> Iterator[tuple[int, str, bytes]]:
    """``(log time ns, topic, bytes)`` of every message of ``bag``, in log-time order."""
    with Reader(bag) as reader:
        for conn, t_ns, raw in reader.messages():
            yield t_ns, conn.topic, raw


def _merge_messages(inputs: Sequence[Path], writer: McapBagWriter) -> None:
    """Every message of ``inputs`` into ``writer``, one at a time (any rosbag2 storage)."""
    write = writer.write
    try:
        for t_ns, topic, raw in heapq.merge(*(_messages(b) for b in inputs),
                                            key=lambda m: m[0]):
            write(topic, t_ns, raw)
    except ReaderError as exc:
        raise BagError(f"cannot merge: {exc}") from None


def merge_bags(inputs: Sequence[Path], out: Path) -> dict[str, int]:
    """Write the messages of ``inputs`` (closed bags, no topic in two of them) into the new
    bag ``out``, in log-time order; returns the messages per topic.

    Raises
    ------
    BagError
        If an input is not a closed bag, a topic is in two inputs, or ``out`` cannot be
        written (then nothing is left at ``out``).
    """
    topics: dict[str, tuple[str, str, Path]] = {}
    published: dict[str, int] = {}
    infos = [_info(bag) for bag in inputs]
    for bag, info in zip(inputs, infos, strict=True):
        for t in info.get("topics_with_message_count") or []:
            meta = t["topic_metadata"]
            name = str(meta["name"])
            if name in topics:
                raise BagError(f"{name}: in {topics[name][2]} and in {bag}: cannot merge")
            qos = meta.get("offered_qos_profiles") or []
            topics[name] = (str(meta["type"]), yaml.safe_dump(qos) if qos else "", bag)
        published.update(read_published(info.get("custom_data")))
    writer = McapBagWriter(out)
    try:
        for name, (msgtype, qos, _) in topics.items():
            writer.add_topic(name, msgtype, qos)
        sources = _sources(inputs, infos, {n: t.channel for n, t in writer.topics.items()})
        if sources is not None:
            _merge_chunks(sources, writer)
        else:
            _merge_messages(inputs, writer)
        if published:
            writer.set_custom_data(PUBLISHED_KEY, json.dumps(published, sort_keys=True))
        counts = writer.counts
        writer.close()
    except BaseException:
        writer.abort()
        raise
    return counts


__all__ = ["merge_bags"]
