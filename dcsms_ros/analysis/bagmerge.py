"""Merge bags of disjoint topics into one bag, messages in log-time order (no rclpy).

``dcsms up --record`` of one process per node writes one bag per node process (the per-sample
topics it publishes, :mod:`dcsms_ros.nodes.recorder_part`) and one of its recorder process
(every other topic); :func:`merge_bags` makes them the one bag the user asked for. Messages
keep their bytes and log times, topics their types and offered QoS profiles, and the
recorders' published counts (``custom_data``) are joined, so the merged bag reads as if one
recorder had written it.
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import yaml
from rosbags.rosbag2 import Reader, ReaderError

from dcsms_ros.analysis.gaps import PUBLISHED_KEY, read_published
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.errors import BagError


def _info(bag: Path) -> dict[str, Any]:
    """A closed bag's ``metadata.yaml`` information."""
    try:
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        raise BagError(f"{bag}: not a closed bag (no readable metadata.yaml)") from None
    if not isinstance(info, dict):
        raise BagError(f"{bag}: not a closed bag (no readable metadata.yaml)")
    return info


def _messages(bag: Path) -> Iterator[tuple[int, str, bytes]]:
    """``(log time ns, topic, bytes)`` of every message of ``bag``, in log-time order."""
    with Reader(bag) as reader:
        for conn, t_ns, raw in reader.messages():
            yield t_ns, conn.topic, raw


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
    for bag in inputs:
        info = _info(bag)
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
        write = writer.write
        try:
            for t_ns, topic, raw in heapq.merge(*(_messages(b) for b in inputs),
                                                key=lambda m: m[0]):
                write(topic, t_ns, raw)
        except ReaderError as exc:
            raise BagError(f"cannot merge into {out}: {exc}") from None
        if published:
            writer.set_custom_data(PUBLISHED_KEY, json.dumps(published, sort_keys=True))
        counts = writer.counts
        writer.close()
    except BaseException:
        writer.abort()
        raise
    return counts


__all__ = ["merge_bags"]
