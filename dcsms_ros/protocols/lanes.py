"""Host lanes: the rules of per-sample delivery between processes of one host without DDS.

One process per node, every per-sample message used to cross Fast DDS: a send per matched
reader, a reception in the reader's DDS thread (a normal-priority thread, which waits behind
every other busy process of a 2-core machine) and a wake-up of the reader's hot thread by that
thread. A *lane* is a FIFO (named pipe) of one reader's subscription, which every writer of
the topic on the same host writes each message into, framed; the reader's SCHED_FIFO hot thread
blocks on it and is woken by the writer's write itself. The transport (:mod:`dcsms_ros.ros.
hostlane`) carries the bytes; this module holds the rules, without ROS or the file system:

* **Frames.** A frame is :data:`HEADER` (payload length, the writer's publication time, system
  clock ns) and the serialized message. A write of at most :data:`MAX_FRAME` bytes into a pipe is
  atomic (POSIX ``PIPE_BUF``), so frames of several writers never interleave and a reader
  always reads whole frames. A message too long for one frame goes on DDS only
  (:meth:`LaneTable.dds`). Control frames (:func:`hello`, :func:`bye`) tell a reader which
  writers serve it.
* **DDS only for the others.** A writer publishes on DDS only while its DDS writer has matched
  more readers than it has lanes, or the graph shows a reader of the topic that no lane serves
  (:meth:`LaneTable.dds`, :func:`readers_without_lane`; the second because a lane reader whose
  DDS reader has not matched yet would hide one that has): a recorder process, ``ros2 topic
  echo``, a node on another host (rclcpp's intra-process rule, for a host).
* **Duplicates.** A lane reader keeps its DDS reader (graph introspection and the graph
  checks see the same graph as without lanes). While every DDS writer it matched has said
  hello on its lane (:meth:`LaneSource.covered`), what arrives on DDS is the lane writers'
  copies for the others and is dropped unread; while a writer without a lane is matched too
  (another process's writer of the topic), DDS is read as well and a DDS message whose bytes
  a lane delivered is dropped, and the other way round: each message cancels one copy
  (:class:`CopyLedger`).
* **Loss.** A lane is written without blocking: a reader that does not keep up (its pipe is
  full) loses the message, and the writer counts it (:attr:`LaneTable.dropped`); the control
  path never waits on an observer.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable, Iterable

#: Frame header: payload length (bytes), publication time (system clock, ns).
HEADER = struct.Struct("<IQ")
#: Longest frame (bytes): POSIX ``PIPE_BUF`` on Linux, the longest write a pipe keeps whole.
MAX_FRAME = 4096
#: Longest message a lane carries (bytes).
MAX_PAYLOAD = MAX_FRAME - HEADER.size
#: Length field of a control frame (its time field is the writer's process id).
HELLO = 0xFFFF_FFFF
BYE = 0xFFFF_FFFE


def frame(data: bytes, t_ns: int) -> bytes:
    """The frame of message ``data`` published at ``t_ns`` (system clock, ns)."""
    return HEADER.pack(len(data), t_ns) + data


def hello(pid: int) -> bytes:
    """The control frame a writer (process ``pid``) sends first on a new lane."""
    return HEADER.pack(HELLO, pid)


def bye(pid: int) -> bytes:
    """The control frame a writer (process ``pid``) sends last, when it closes a lane."""
    return HEADER.pack(BYE, pid)


class FrameBuffer:
    """Bytes read from a lane, cut into frames (a read may end inside a frame when the
    reader's buffer was shorter than what was queued; the rest waits for the next read)."""

    def __init__(self) -> None:
        self._rest = b""
        #: Writers (process ids) that said hello and not bye, in order of arrival.
        self.hellos: list[int] = []
        self.byes: list[int] = []

    def feed(self, chunk: bytes) -> list[tuple[bytes, int]]:
        """The messages (payload, publication time ns) completed by ``chunk``, oldest first;
        control frames go to :attr:`hellos` / :attr:`byes`."""
        buf = self._rest + chunk if self._rest else chunk
        out: list[tuple[bytes, int]] = []
        i, n, hs = 0, len(buf), HEADER.size
        unpack = HEADER.unpack_from
        while i + hs <= n:
            ln, t = unpack(buf, i)
            if ln >= BYE:
                (self.hellos if ln == HELLO else self.byes).append(t)
                i += hs
                continue
            end = i + hs + ln
            if end > n:
                break
            out.append((buf[i + hs:end], t))
            i = end
        self._rest = buf[i:] if i < n else b""
        return out


class LaneSource:
    """What one lane reader knows of its writers: which processes serve it on the lane
    (hello, not bye, still alive), against the DDS writers its DDS reader matched.

    Parameters
    ----------
    alive : callable
        ``alive(pid)`` -> bool: whether a writer's process still runs (a killed writer says
        no bye).
    """

    def __init__(self, alive: Callable[[int], bool]) -> None:
        self._alive = alive
        self.writers: list[int] = []
        #: Counts the changes of :attr:`writers`: what was judged from them holds while it
        #: stays the same.
        self.version = 0

    def update(self, hellos: Iterable[int], byes: Iterable[int]) -> None:
        """Record control frames (in the order they were read)."""
        for pid in hellos:
            if pid not in self.writers:
                self.writers.append(pid)
                self.version += 1
        for pid in byes:
            if pid in self.writers:
                self.writers.remove(pid)
                self.version += 1

    def prune(self) -> None:
        """Forget writers whose process is gone."""
        alive = [p for p in self.writers if self._alive(p)]
        if len(alive) != len(self.writers):
            self.writers = alive
            self.version += 1

    def covered(self, dds_writers: int) -> bool:
        """True when every one of the ``dds_writers`` DDS writers the reader matched can be a
        lane writer, and there is one: DDS then carries only copies."""
        return bool(self.writers) and len(self.writers) >= dds_writers

    def foreign(self, dds_writers: int) -> int:
        """DDS writers the lanes cannot account for (another process's writer of the topic)."""
        return max(dds_writers - len(self.writers), 0)


class CopyLedger:
    """Messages delivered one way (lane or DDS) whose copy may still come the other way: each
    delivered message cancels exactly one copy of its bytes, whenever that copy comes (a
    reliable DDS copy may be retransmitted hundreds of milliseconds later), and a second
    message of the same bytes (a lockstep retransmission) is delivered again.

    Parameters
    ----------
    size : int
        How many uncancelled messages are remembered (the oldest are forgotten: a copy that
        never came, e.g. lost on best-effort DDS).
    """

    def __init__(self, size: int = 4096) -> None:
        self.size = size
        self._order: deque[bytes] = deque()
        self._count: dict[bytes, int] = {}

    def add(self, data: bytes) -> None:
        """``data`` was delivered: its copy, when it comes, is to be dropped."""
        self._order.append(data)
        self._count[data] = self._count.get(data, 0) + 1
        while len(self._order) > self.size:
            self._forget(self._order.popleft())

    def cancel(self, data: bytes) -> bool:
        """True (and forgotten) if ``data`` is the copy of a delivered message."""
        if data not in self._count:
            return False
        self._forget(data)
        self._order.remove(data)
        return True

    def _forget(self, data: bytes) -> None:
        left = self._count[data] - 1
        if left:
            self._count[data] = left
        else:
            del self._count[data]

    def __len__(self) -> int:
        return len(self._order)


def readers_without_lane(readers: Iterable[str], lane_owners: Iterable[str]) -> int:
    """How many of the topic's ``readers`` (the graph's subscriptions, by node name, one entry
    each) are not served by one of the open lanes (whose readers' node names are
    ``lane_owners``): a node's subscriptions beyond its lanes, and every reader of another
    node (a recorder process, a tool, a node on another host, or one not announced yet)."""
    lanes: dict[str, int] = {}
    for owner in lane_owners:
        lanes[owner] = lanes.get(owner, 0) + 1
    out = 0
    for node in readers:
        if lanes.get(node, 0) > 0:
            lanes[node] -= 1
        else:
            out += 1
    return out


class LaneTable:
    """A writer's lanes' bookkeeping and its decision per message: whether DDS too."""

    def __init__(self) -> None:
        #: Messages a full lane could not take, per lane name.
        self.dropped: dict[str, int] = {}
        #: Messages written to at least one lane.
        self.sent = 0

    @staticmethod
    def dds(matched: int, lanes: int, size: int, outside: int = 0) -> bool:
        """True if a message of ``size`` bytes must go on DDS: it is too long for a lane, DDS
        matched more readers than there are lanes (``matched`` DDS readers, ``lanes`` open
        lanes), or the graph shows ``outside`` readers that have no lane (a lane reader whose
        DDS reader has not matched yet must not hide one that has)."""
        return size > MAX_PAYLOAD or matched > lanes or outside > 0

    def drop(self, lane: str) -> None:
        """Count a message lane ``lane`` could not take (its pipe was full)."""
        self.dropped[lane] = self.dropped.get(lane, 0) + 1

    @property
    def drops(self) -> int:
        """Messages lost on full lanes, in all."""
        return sum(self.dropped.values())


__all__ = [
    "BYE",
    "HEADER",
    "HELLO",
    "MAX_FRAME",
    "MAX_PAYLOAD",
    "CopyLedger",
    "FrameBuffer",
    "LaneSource",
    "LaneTable",
    "bye",
    "frame",
    "hello",
    "readers_without_lane",
]
