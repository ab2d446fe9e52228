"""The bag writer process: ``python -m dcsms_ros.analysis.bagserve OUT [STORAGE]``.

Started by :class:`~dcsms_ros.analysis.bagprocess.ProcessBagWriter`. It creates the bag ``OUT``
and prints one JSON line on its standard output, ``{"ready": true}`` or ``{"error": "..."}``;
then reads frames (:mod:`.bagframes`) on its standard input and writes their messages into the
bag (chunks compressed here, off the writer's process), keeping the counters of the topics
announced with ``stats``. After :data:`~.bagframes.CLOSE` it closes the bag and prints
``{"path": ..., "stats": {topic: state}}`` (:meth:`.TopicStats.state`), then exits 0; after
:data:`~.bagframes.ABORT` it removes the bag.

It outlives nothing it serves: end of input without a last frame (the writing process died)
closes the bag with what arrived, says so on stderr and exits 1. SIGINT and SIGTERM are
ignored: Ctrl-C reaches the whole process group, and the process that writes decides when
the bag ends (it sends :data:`~.bagframes.CLOSE` after its own drain).
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import signal
import sys
from collections.abc import Sequence
from typing import Any

from dcsms_ros.analysis.bagframes import ABORT, CLOSE, CUSTOM, LOST, MESSAGE, TOPIC, FrameReader
from dcsms_ros.analysis.bagio import BagWriter, new_writer
from dcsms_ros.analysis.gaps import PUBLISHED_KEY, TopicStats, published_json, read_published
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.cdr import read_stamp
from dcsms_ros.errors import DcsmsError

#: Bytes asked of the pipe per read.
READ_BYTES = 1 << 20
#: ``prctl`` option (linux/prctl.h): the name of the calling thread (``comm``).
_PR_SET_NAME = 15


class Served:
    """The state of one served bag: its writer, the announced topics and their counters."""

    def __init__(self, writer: McapBagWriter | BagWriter) -> None:
        self.writer = writer
        #: topic id -> (name, counters or None)
        self.topics: dict[int, tuple[str, TopicStats | None]] = {}
        #: the bag's custom data, set when it closes
        self.custom: dict[str, str] = {}

    def take(self, frames: Sequence[tuple[int, int, int, int, bytes]]) -> int | None:
        """Write ``frames``; returns the last frame's kind if it ended the bag, else None."""
        topics = self.topics
        batch: list[tuple[str, int, bytes]] = []
        for kind, tid, seq, t_ns, payload in frames:
            if kind == MESSAGE:
                name, st = topics[tid]
                batch.append((name, t_ns, payload))
                if st is not None:
                    st.add(seq if seq >= 0 else None,
                           read_stamp(payload) if st.stamped else None, t_ns)
                continue
            if batch:
                self.writer.write_all(batch)
                batch = []
            if kind == TOPIC:
                meta = json.loads(payload)
                self.writer.add_topic(meta["topic"], meta["type"], meta["qos"])
                st = (TopicStats(meta["topic"], meta["type"], bool(meta["stamped"]))
                      if meta["stats"] else None)
                topics[tid] = (meta["topic"], st)
            elif kind == LOST:
                st = topics[tid][1]
                if st is not None:
                    st.lost_through(seq)
            elif kind == CUSTOM:
                self.custom.update(json.loads(payload))
            elif kind in (CLOSE, ABORT):
                return kind
        if batch:
            self.writer.write_all(batch)
        return None

    def counters(self) -> list[TopicStats]:
        """The counters kept here, finished (the bag is about to close)."""
        out = [st for _, st in self.topics.values() if st is not None]
        for st in out:
            st.finish()
        return out

    def close(self) -> dict[str, Any]:
        """Close the bag; the line to print. The topics counted here join the publishers'
        counts the writing process left in the custom data (:data:`.gaps.PUBLISHED_KEY`)."""
        stats = self.counters()
        if stats:
            published = read_published(self.custom)
            published.update(json.loads(published_json(stats)))
            self.custom[PUBLISHED_KEY] = json.dumps(published, sort_keys=True)
        for key, value in self.custom.items():
            self.writer.set_custom_data(key, value)
        path = self.writer.close()
        return {"path": str(path), "stats": {st.topic: st.state() for st in stats}}


def serve(out: str, storage: str, fd_in: int, emit: Any) -> int:
    """Serve one bag (see the module notes); ``emit(dict)`` prints a result line."""
    try:
        writer = new_writer(out, storage)
    except DcsmsError as exc:
        emit({"error": str(exc)})
        return 2
    emit({"ready": True})
    served = Served(writer)
    reader = FrameReader()
    end: int | None = None
    try:
        while end is None:
            piece = os.read(fd_in, READ_BYTES)
            if not piece:
                break
            end = served.take(list(reader.feed(piece)))
        if end == ABORT:
            writer.abort()
            return 0
        result = served.close()
    except (DcsmsError, KeyError, ValueError) as exc:  # a write failed, or a bad frame
        emit({"error": str(exc) if isinstance(exc, DcsmsError) else f"{out}: bad frame: {exc!r}"})
        try:  # what arrived stays
            writer.close()
        except DcsmsError:
            writer.abort()
        return 2
    if end is None:
        print(f"bagserve: the writing process ended without closing {out}; closed with what "
              f"arrived{' (its last frame cut)' if reader.partial else ''}", file=sys.stderr)
        return 1
    emit(result)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point (see the module notes)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not 1 <= len(args) <= 2:
        print("usage: python -m dcsms_ros.analysis.bagserve OUT [STORAGE]", file=sys.stderr)
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    with contextlib.suppress(OSError, AttributeError):  # named when its command line is gone
        ctypes.CDLL(None).prctl(_PR_SET_NAME, b"bagserve", 0, 0, 0)

    def emit(value: dict[str, Any]) -> None:
        sys.stdout.write(json.dumps(value) + "\n")
        sys.stdout.flush()

    return serve(args[0], args[1] if len(args) > 1 else "mcap", sys.stdin.fileno(), emit)


if __name__ == "__main__":
    sys.exit(main())
