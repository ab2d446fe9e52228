"""The recorder inside a node's own process (``dcsms up --record``, one process per node).

A recorder process takes every message over DDS. At 2 kHz the graph's eleven per-sample
topics are 22,000 messages/s, each costing a DDS reception (~45 us) in the recorder and a
send in its writer; on two cores that made the recorded per-process graph CPU-bound (stale
forces 2.2-4.5 % of 120,000 recorded, 0-0.2 % unrecorded: docs/performance.md). So each node
process records the per-sample topics it publishes itself, as it publishes them (the bytes
and the system time of the publication as the bag time), into a bag of its own, the
*part*; ``dcsms up`` merges the parts and its recorder process's bag (every other topic) into
the one bag asked for (:func:`dcsms_ros.analysis.bagmerge.merge_bags`). It is the composed
recorder's rule (it takes the bus's bytes) for a process of one node.

``dcsms up`` asks for it with :data:`~dcsms_ros.graph.RECORD_PART_ENV` (the part's bag
directory) and :data:`~dcsms_ros.graph.RECORD_TOPICS_ENV` (the topics); without them a node
records nothing, as under ``ros2 run``. The hot thread gathers its messages (after each one
went to its readers) and writes them :data:`PART_BATCH` at a time, one warm pass through the
writer instead of one cold call a sample (4 alternating pairs of 30 s real time, recording
on: CPU per sample 7-30 us less in the plant, 6-18 less in the decoupling in 3 pairs and 6 more
in one, 2-16 less in a controller; late samples 189 / 211 / 218 / 220 against 241 / 280 / 265 /
192); :meth:`PartRecorder.finish` writes the rest. Full chunks are compressed and written by
the node's executor, outside the hot-path lock
(:class:`~dcsms_ros.ros.callbackgroups.UnlockedGroup`: under it, the hot thread waited for each
chunk and the plant's late samples doubled, docs/performance.md).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rclpy.node import Node

from dcsms_ros.analysis.gaps import PUBLISHED_KEY
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.errors import BagError, DcsmsError
from dcsms_ros.graph import RECORD_PART_ENV, RECORD_TOPICS_ENV
from dcsms_ros.nodes.recorder_topics import qos_yaml
from dcsms_ros.ros.callbackgroups import UnlockedGroup
from dcsms_ros.ros.graphnode import GraphNode
from dcsms_ros.ros.hosted import hot_path
from dcsms_ros.ros.intraprocess import Deferred, DirectPublisher

#: Period of the part's flush, s. Every executor round holds the GIL in Python while the node's
#: hot thread may need it (:data:`~dcsms_ros.ros.context.HOST_POLL_S`), so the flush runs
#: with the node's 1 s report rather than every 0.25 s as the recorder's: 4 alternating pairs
#: of 20 s per-process runs, late samples 140-182 against 183-342, fewer in every pair; the
#: late samples had clustered at the 0.25 s phase (56-65 % in a fifth of it). A full chunk is
#: 4 MB, so at most about a second of the node's messages more waits in memory.
PART_FLUSH_PERIOD_S = 1.0


#: Messages the hot thread gathers before it writes them into the part at once (a batch is
#: ~0.1 ms of the writer's time: 13 of the plant's samples, 64 of a controller's).
PART_BATCH = 64


def msgtype_name(cls: Any) -> str:
    """``pkg/msg/Name`` of a generated message class."""
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


class PartRecorder:
    """Record the topics ``topics`` that ``node`` publishes through its hot path.

    Parameters
    ----------
    node : rclpy Node
        A node with a hot path, before its hot loop starts.
    out : str
        The part's bag directory (must not exist).
    topics : collection of str
        Absolute topic names to record, where the node publishes them.

    Raises
    ------
    BagError
        If the bag cannot be created.
    """

    def __init__(self, node: Node, out: str, topics: set[str] | frozenset[str]) -> None:
        hot = hot_path(node)
        mine = [w for w in (hot.writers if hot is not None else [])
                if isinstance(w, DirectPublisher) and w.topic_name in topics]
        self.writer = McapBagWriter(out, defer_flush=True)
        self._open = True
        self._batch: list[tuple[str, int, Any]] = []  # bytes, or Deferred until written
        try:
            for w in mine:
                name = msgtype_name(w.pub.msg_type)
                self.writer.add_topic(w.topic_name, name, qos_yaml([w.pub.qos_profile]))
                w.observe(self._observer(w.topic_name))
        except BaseException:
            self.writer.abort()
            raise
        if isinstance(node, GraphNode):  # the writer is thread-safe: not under the hot lock
            node.housekeeping(PART_FLUSH_PERIOD_S, self.writer.flush, UnlockedGroup())

    def _observer(self, topic: str) -> Any:
        # every publication is observed, so no gap can hide and what was published is the
        # part's count
        batch = self._batch

        def cb(data: bytes | Deferred, t_ns: int) -> None:
            if self._open:
                batch.append((topic, t_ns, data))
                if len(batch) >= PART_BATCH:
                    self._write_batch()

        return cb

    def _write_batch(self) -> None:
        batch = self._batch
        if batch:
            for i, (topic, t_ns, data) in enumerate(batch):
                if data.__class__ is tuple:  # Deferred: encoded here, in one warm pass
                    enc, ns, value = data
                    batch[i] = (topic, t_ns, enc(ns, value))
            self.writer.write_all(batch)
            batch.clear()

    def finish(self) -> Path:
        """Close the part (after the node's hot loop and final reports); every message was
        written, so what was published is what the part holds. Returns its path."""
        self._open = False
        self._write_batch()
        self.writer.set_custom_data(PUBLISHED_KEY, json.dumps(self.writer.counts,
                                                              sort_keys=True))
        return self.writer.close()

    def abort(self) -> None:
        """Remove the unfinished part (the node failed before it ran)."""
        self._open = False
        self.writer.abort()


def attach(node: Node, env: Mapping[str, str] | None = None) -> PartRecorder | None:
    """The part recorder ``env`` (default the process's) asks ``node`` for, or None.

    Raises
    ------
    DcsmsError
        If the part cannot be created (one line for the node's log and exit status).
    """
    env = os.environ if env is None else env
    out = env.get(RECORD_PART_ENV, "")
    if not out:
        return None
    try:
        return PartRecorder(node, out, frozenset(env.get(RECORD_TOPICS_ENV, "").split()))
    except BagError as exc:
        raise DcsmsError(f"{RECORD_PART_ENV}: {exc}") from None


__all__ = ["PART_BATCH", "PART_FLUSH_PERIOD_S", "PartRecorder", "attach", "msgtype_name"]
