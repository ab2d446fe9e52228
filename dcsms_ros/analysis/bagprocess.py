"""A bag written by another process: :class:`ProcessBagWriter`.

A composed graph records in its own process (:mod:`dcsms_ros.nodes.recorder`), on its one
real-time driver thread. Writing a message there (the chunk append, the counters, the header
stamp read) was about a third of the recorded lockstep step: the driver's CPU 85-86 us a step
recorded, 59-62 not (docs/performance.md). Here the driver only frames each batch of messages
and writes it to a pipe (~0.4 us a message); the bag writer process (:mod:`.bagserve`), on the
other core (``cpus``: under SCHED_FIFO the host starts it off the driver's core), writes the bag
and keeps the counters.

The pipe never makes a real-time writer wait: it is non-blocking; the frames gather in a
backlog, written once :data:`WRITE_BYTES` wait (or at :meth:`ProcessBagWriter.flush`), and what
the pipe does not take then waits for the next write. Beyond
:data:`BACKLOG_BYTES` a ``lossless`` writer (lockstep: a reliable reader's rule) waits for the
process; otherwise the new messages are dropped and counted (:attr:`ProcessBagWriter.dropped`;
the process sees them as a gap in the publisher's numbers). Topics, custom data and the end
are never dropped. If the process dies the messages are counted as dropped and :meth:`close`
raises.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import select
import subprocess
import sys
import threading
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from dcsms_ros.analysis.bagframes import (
    ABORT,
    CLOSE,
    CUSTOM,
    LOST,
    MAX_TOPICS,
    MESSAGE,
    TOPIC,
    pack_frame,
    pack_json,
    pack_messages,
)
from dcsms_ros.analysis.gaps import TopicStats
from dcsms_ros.errors import BagError

#: Bytes that may wait for the process beyond what the pipe holds: ~13 s of the eleven
#: per-sample topics at 2 kHz (2.4 MB/s).
BACKLOG_BYTES = 32 << 20
#: Bytes gathered before a write: each write wakes the process, whose wake-up the writer pays
#: (one write a 64-message batch was ~3 % of the composed lockstep step, py-spy).
WRITE_BYTES = 64 << 10
#: The pipe's size asked for (``F_SETPIPE_SZ``; Linux's default limit for a user is 1 MiB).
PIPE_BYTES = 1 << 20
#: How long :meth:`ProcessBagWriter.close` waits for the process to finish the bag (s).
CLOSE_TIMEOUT_S = 120.0
_F_SETPIPE_SZ = 1031


@contextlib.contextmanager
def _forking_on(cpus: frozenset[int] | None) -> Iterator[None]:
    """The calling thread on ``cpus`` while the block runs: a process it forks keeps them,
    every thread of it too (set from outside, a thread it had started already would not).
    CPUs the kernel refuses (none of them usable) leave the thread's own."""
    before = os.sched_getaffinity(0)
    try:
        if cpus is not None:
            os.sched_setaffinity(0, cpus)
    except OSError:
        cpus = None
    if cpus is None:
        yield
        return
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


class ProcessBagWriter:
    """Write the new bag ``out`` in a bag writer process (see the module notes).

    Thread-safe: a composed recorder writes from its executor and from the driver thread.

    Parameters
    ----------
    out : str or Path
        The bag directory (must not exist).
    storage : str
        ``mcap`` or ``sqlite3``.
    lossless : bool
        Wait for the process rather than drop messages (see the module notes).
    backlog_bytes : int
        :data:`BACKLOG_BYTES`.
    cpus : frozenset of int, optional
        The CPUs the process runs on (None: those of the calling thread).

    Attributes
    ----------
    dropped : int
        Messages not written (the backlog was full, or the process had died).
    stats : dict of str to TopicStats
        After :meth:`close`: the counters the process kept (the topics added with ``stats``).
    """

    def __init__(self, out: str | Path, storage: str = "mcap", lossless: bool = True,
                 backlog_bytes: int = BACKLOG_BYTES, cpus: frozenset[int] | None = None
                 ) -> None:
        self.path = Path(out)
        self.lossless = lossless
        self.backlog_bytes = backlog_bytes
        self.dropped = 0
        self.stats: dict[str, TopicStats] = {}
        self._ids: dict[str, int] = {}
        self._lost: dict[int, int] = {}  # topic id -> the last number dropped
        self._lock = threading.Lock()
        self._backlog: deque[bytes | memoryview] = deque()
        self._waiting = 0  # bytes in the backlog
        self._unwritten = 0  # messages in the backlog (some may be written in part)
        self._dead = False  # the pipe broke
        self._ended = False  # the last frame went
        self._ready = False
        with _forking_on(cpus):
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "dcsms_ros.analysis.bagserve", str(out), storage],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._out: IO[bytes] = self._proc.stdout
        self._stdin: IO[bytes] = self._proc.stdin  # written through its descriptor only
        self._fd = self._stdin.fileno()
        try:
            fcntl.fcntl(self._fd, _F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:  # a lower limit: the default pipe and the backlog
            pass
        os.set_blocking(self._fd, False)

    # -- the process's answers ----------------------------------------------------------------
    def _answer(self) -> dict[str, Any]:
        line = self._out.readline()
        try:
            value = json.loads(line) if line else None
        except ValueError:
            value = None
        if not isinstance(value, dict):
            code = self._proc.wait()
            raise BagError(f"{self.path}: the bag writer process exited {code}")
        if "error" in value:
            self._proc.wait()
            raise BagError(str(value["error"]))
        return value

    def wait_ready(self) -> None:
        """Wait until the process created the bag (the first :meth:`add_topic` does).

        Raises
        ------
        BagError
            The bag cannot be created (its message), or the process did not start.
        """
        if not self._ready:
            self._answer()
            self._ready = True

    # -- writing ------------------------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, qos_yaml: str = "", stats: bool = False,
                  stamped: bool = False) -> int:
        """Add ``topic``; returns its id for :meth:`write_frames`. ``stats``: the process
        keeps its :class:`TopicStats` (``stamped``: from the header stamps too)."""
        self.wait_ready()
        if topic in self._ids:
            raise BagError(f"{self.path}: topic {topic} added twice")
        if len(self._ids) >= MAX_TOPICS:
            raise BagError(f"{self.path}: more than {MAX_TOPICS} topics")
        tid = self._ids[topic] = len(self._ids)
        self._send(pack_json(TOPIC, {"topic": topic, "type": msgtype, "qos": qos_yaml,
                                     "stats": stats, "stamped": stamped}, tid))
        return tid

    def write(self, topic: str, t_ns: int, data: bytes) -> None:
        """One message of ``topic`` (publisher's number unknown)."""
        try:
            tid = self._ids[topic]
        except KeyError:
            raise BagError(f"{self.path}: topic {topic} was not added") from None
        self._send(pack_frame(MESSAGE, tid, data, -1, t_ns), 1)

    def write_frames(self, batch: list[tuple[int, bytes, int, int]]) -> None:
        """Messages ``(topic id, data, publisher's number, t_ns)``, in their order (a bus
        observer's batch, :class:`~dcsms_ros.protocols.localbus.Sink`, tagged with the id)."""
        if not self._send(pack_messages(batch), len(batch)):
            lost = self._lost
            for tid, _, seq, _ in batch:
                if seq > lost.get(tid, 0):
                    lost[tid] = seq

    def set_custom_data(self, key: str, value: str) -> None:
        """An entry of the bag's ``custom_data``."""
        self._send(pack_json(CUSTOM, {key: value}))

    def flush(self) -> None:
        """Write what waits, as far as the pipe takes it now."""
        with self._lock:
            self._drain()

    def _send(self, data: bytes, messages: int = 0) -> bool:
        """Queue ``data`` (``messages`` of them); write once :data:`WRITE_BYTES` wait. False
        if the messages were dropped."""
        with self._lock:
            if self._dead or self._ended or (messages and not self.lossless and
                                             self._waiting >= self.backlog_bytes):
                self.dropped += messages
                return False
            self._backlog.append(data)
            self._waiting += len(data)
            self._unwritten += messages
            if self._waiting >= WRITE_BYTES:
                self._drain(self.backlog_bytes if self.lossless else None)
            return True

    def _drain(self, wait_to: int | None = None) -> None:
        """Write the backlog as far as the pipe takes it, up to :data:`PIPE_BYTES` a call;
        ``wait_to``: wait for the process until at most that many bytes wait (-1: every byte
        written)."""
        q = self._backlog
        while q:
            if len(q) > 1 and len(q[0]) < PIPE_BYTES:
                parts = [q.popleft()]
                size = len(parts[0])
                while q and size + len(q[0]) <= PIPE_BYTES:
                    size += len(q[0])
                    parts.append(q.popleft())
                q.appendleft(b"".join(parts))
            data = q[0]
            try:
                done = os.write(self._fd, data)
            except BlockingIOError:
                if wait_to is None or self._waiting <= wait_to:
                    return
                select.select([], [self._fd], [], 1.0)
                continue
            except OSError:  # BrokenPipeError: the process died
                self._dead = True
                self.dropped += self._unwritten
                q.clear()
                self._waiting = self._unwritten = 0
                return
            self._waiting -= done
            if done == len(data):
                q.popleft()
            else:
                q[0] = memoryview(data)[done:]
        self._unwritten = 0

    # -- the end ------------------------------------------------------------------------------
    def close(self) -> Path:
        """Write everything, close the bag (the process renames it into place), return its
        path; :attr:`stats` then holds the process's counters.

        Raises
        ------
        BagError
            The process failed or had died (what it wrote is in the bag if it closed it).
        """
        self.wait_ready()
        for tid, seq in sorted(self._lost.items()):
            self._send(pack_frame(LOST, tid, seq=seq))
        self._finish(pack_frame(CLOSE))
        try:
            value = self._answer()
        except BagError as exc:
            raise BagError(f"{exc}; {self.dropped} messages not written" if self.dropped
                           else str(exc)) from None
        self._proc.wait(timeout=CLOSE_TIMEOUT_S)
        self.stats = {t: TopicStats.from_state(s) for t, s in value.get("stats", {}).items()}
        return Path(value["path"])

    def abort(self) -> None:
        """Remove the unfinished bag (the process removes it) and end the process."""
        try:
            self._finish(pack_frame(ABORT))
            self._proc.wait(timeout=10.0)
        except (OSError, subprocess.TimeoutExpired):
            self._proc.kill()
            self._proc.wait()

    def _finish(self, last: bytes) -> None:
        self._send(last)
        with self._lock:
            self._drain(-1)
            self._ended = True
        try:
            self._stdin.close()  # the end of input: the process's, if it missed the frame
        except OSError:
            pass


__all__ = ["BACKLOG_BYTES", "PIPE_BYTES", "WRITE_BYTES", "ProcessBagWriter"]
