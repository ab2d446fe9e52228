"""Host lanes on the file system: each lane reader's FIFO, and the writers that find it.

The rules (frames, when DDS is needed too, duplicates, loss) are
:mod:`dcsms_ros.protocols.lanes`; this module is the transport, for one process per node
(a composed process hands messages over in the process, :mod:`.intraprocess`):

* **Where.** ``<root>/dcsms-lanes-<uid>/<netns>-<pidns>-<domain>/<topic>/<pid>.<n>``: one
  directory per user (mode 0700), per network and process-id namespace and ROS domain (two
  "hosts" made of network namespaces on one machine, two containers, or two domains never
  share a lane; DDS connects them as before), per topic; ``root`` is ``/dev/shm`` (a FIFO
  takes no space), else the temporary directory.
* **Readers.** A hot-path subscription of one process per node creates its FIFO, opens it
  read-write (so that it never sees end-of-file and its open never waits) and non-blocking,
  and reads it from the hot thread (:class:`LaneReader`). A reader removes its FIFO when it
  closes, and any reader removes FIFOs of processes that are gone.
* **Writers.** A per-sample publisher (:class:`LaneWriter`) lists its topic's directory when its
  DDS writer's matched count changes and every :data:`REFRESH_S`, opens each FIFO write-only
  and non-blocking (the open fails while no process reads it: a reader that was killed), says
  hello, and writes every message into every lane; a write to a reader that is gone fails and
  closes that lane. A transient-local writer (the lockstep velocities and applied forces) does
  not use lanes: its late DDS readers get its history from DDS.

``DCSMS_HOST_LANES=0`` in the environment turns lanes off (every message on DDS, as before);
``ROS_AUTOMATIC_DISCOVERY_RANGE=OFF`` does too (no DDS peers, so no lane peers either).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import itertools
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from dcsms_ros.protocols.lanes import (
    MAX_PAYLOAD,
    FrameBuffer,
    LaneSource,
    LaneTable,
    bye,
    frame,
    hello,
    readers_without_lane,
)

#: The environment variable that turns lanes off (``0``, ``false``, ``no``, ``off``).
ENV = "DCSMS_HOST_LANES"
#: How often a writer looks for new readers of its topic when its DDS count did not change (s):
#: a reader replaced by another between two looks (a restarted node) is found within it. A
#: look lists the topic's directory and asks the graph's reader count (~7 us).
REFRESH_S = 0.1
#: Pipe buffer asked for each lane (bytes; Linux's unprivileged maximum): ~6,000 frames, 3 s
#: of one 2 kHz topic, for a reader that drains in blocks (mode_switch every 50 ms).
PIPE_SIZE = 1 << 20
#: Bytes one read takes from a lane.
READ_SIZE = 1 << 16

_serial = itertools.count(1)


def enabled() -> bool:
    """Whether lanes are on: not turned off by :data:`ENV`, and DDS discovery not off."""
    if os.environ.get(ENV, "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    return os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper() != "OFF"


def host_key(domain: int) -> str:
    """``<network namespace>-<process id namespace>-<ROS domain id>`` (namespaces by inode):
    processes with the same key may share lanes (a writer tells a gone reader by its process
    id, so both must see the same ids)."""
    ns = []
    for kind in ("net", "pid"):
        try:
            ns.append(os.stat(f"/proc/self/ns/{kind}").st_ino)
        except OSError:  # no procfs: one namespace as far as we can tell
            ns.append(0)
    return f"{ns[0]}-{ns[1]}-{domain}"


def lane_root(domain: int, base: Path | None = None) -> Path:
    """The directory of this user's lanes on this host in ROS domain ``domain`` (its parent
    created, mode 0700)."""
    if base is None:
        shm = Path("/dev/shm")
        base = shm if shm.is_dir() and os.access(shm, os.W_OK) else Path(tempfile.gettempdir())
    top = base / f"dcsms-lanes-{os.getuid()}"
    top.mkdir(mode=0o700, exist_ok=True)
    return top / host_key(domain)


def topic_dir(topic: str, root: Path) -> Path:
    """The directory of ``topic``'s lanes (a fully resolved name) under ``root``."""
    return root / topic.strip("/").replace("/", "%")


def pid_alive(pid: int) -> bool:
    """True if process ``pid`` exists."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def lane_name(node: str) -> str:
    """A new lane's file name: ``<pid>.<n>.<reader's node, / as %>``."""
    return f"{os.getpid()}.{next(_serial)}.{node.replace('/', '%')}"


def _owner(name: str) -> int | None:
    head = name.split(".", 1)[0]
    return int(head) if head.isdigit() else None


def _owner_node(name: str) -> str:
    parts = name.split(".", 2)
    return parts[2].replace("%", "/") if len(parts) == 3 else ""


class LaneReader:
    """One subscription's lane: its FIFO, opened for reading by this process.

    Parameters
    ----------
    topic : str
        Fully resolved topic name.
    root : Path
        The lanes' directory (:func:`lane_root`).
    node : str
        The reading node's fully qualified name (writers tell its DDS reader by it).
    pipe_size : int
        The pipe buffer to ask for, bytes.
    """

    def __init__(self, topic: str, root: Path, node: str, pipe_size: int = PIPE_SIZE) -> None:
        self.topic = topic
        d = topic_dir(topic, root)
        d.mkdir(parents=True, exist_ok=True)
        for name in os.listdir(d):  # FIFOs of killed readers
            pid = _owner(name)
            if pid is not None and pid != os.getpid() and not pid_alive(pid):
                with contextlib.suppress(OSError):
                    os.unlink(d / name)
        self.path = d / lane_name(node)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)
        os.mkfifo(self.path, 0o600)
        self.fd = os.open(self.path, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)
        #: Why the kernel refused ``pipe_size`` (empty if it did not).
        self.refused = ""
        try:
            fcntl.fcntl(self.fd, fcntl.F_SETPIPE_SZ, pipe_size)
        except OSError as exc:  # the user's pipe quota or fs.pipe-max-size: 64 KiB still works
            self.refused = exc.strerror or str(exc)
        #: The pipe buffer the lane has, bytes.
        self.capacity = int(fcntl.fcntl(self.fd, fcntl.F_GETPIPE_SZ))
        self._buf = FrameBuffer()
        #: The lane writers serving this reader.
        self.source = LaneSource(pid_alive)
        self._prune_at = 0.0

    def read(self) -> list[tuple[bytes, int]]:
        """Every message queued (payload, publication time ns), oldest first."""
        out: list[tuple[bytes, int]] = []
        fd, buf = self.fd, self._buf
        while True:
            try:
                chunk = os.read(fd, READ_SIZE)
            except BlockingIOError:
                break
            got = buf.feed(chunk)
            if got:
                out += got
            if len(chunk) < READ_SIZE:
                break
        if buf.hellos or buf.byes:
            self.source.update(buf.hellos, buf.byes)
            buf.hellos.clear()
            buf.byes.clear()
        return out

    def writers(self, now: float) -> int:
        """How many lane writers serve this reader (the gone ones forgotten every
        :data:`REFRESH_S`; ``now``: monotonic s)."""
        if now >= self._prune_at:
            self._prune_at = now + REFRESH_S
            self.source.prune()
        return len(self.source.writers)

    def close(self) -> None:
        """Close and remove the FIFO (idempotent)."""
        if self.fd < 0:
            return
        with contextlib.suppress(OSError):
            os.close(self.fd)
        self.fd = -1
        with contextlib.suppress(OSError):
            os.unlink(self.path)


class LaneWriter:
    """One publisher's lanes: every reader's FIFO of its topic on this host.

    Parameters
    ----------
    topic : str
        Fully resolved topic name.
    root : Path
        The lanes' directory (:func:`lane_root`).
    readers : callable, optional
        ``readers()`` -> (the fully qualified node name of each subscription of the topic in
        the graph, whether every one's node is known), asked when ``count()`` or the lanes
        changed, and at each look while a node is unknown: a reader outside the lanes gets DDS
        even while lane readers not matched yet keep the matched count low.
    count : callable, optional
        ``count()`` -> how many subscriptions the graph shows (cheap: asked at each look).
    """

    def __init__(self, topic: str, root: Path,
                 readers: Callable[[], tuple[Sequence[str], bool]] = lambda: ((), True),
                 count: Callable[[], int] = lambda: 0) -> None:
        self.topic = topic
        self.dir = topic_dir(topic, root)
        self.lanes: dict[str, int] = {}
        self.table = LaneTable()
        self._readers, self._count = readers, count
        #: Readers the graph shows that no lane serves.
        self.outside = 0
        #: Lanes closed because their reader went (its FIFO removed, or a write found it gone).
        self.left = 0
        self._graph = -1
        self._unsure = False
        self._due = 0
        self._matched = -1
        self._pid = os.getpid()
        self._hello = hello(self._pid)

    def refresh(self) -> None:
        """Open a lane to every reader of the topic that has none yet, close the lanes of
        readers that are gone; count the graph's readers without a lane."""
        before = set(self.lanes)
        self._open()
        graph = self._count()
        if graph != self._graph or set(self.lanes) != before or self._unsure:
            self._graph = graph
            readers, known = self._readers()
            self._unsure = not known  # a reader's node not announced yet: asked at each look
            self.outside = readers_without_lane(readers, map(_owner_node, self.lanes))

    def _open(self) -> None:
        try:
            names = set(os.listdir(self.dir))
        except FileNotFoundError:
            names = set()
        for name in list(self.lanes):
            if name not in names:
                self._close(name)
                self.left += 1
        for name in names - self.lanes.keys():
            try:
                fd = os.open(self.dir / name, os.O_WRONLY | os.O_NONBLOCK | os.O_CLOEXEC)
            except OSError:  # nobody reads it (ENXIO), or it went meanwhile
                continue
            try:
                os.write(fd, self._hello)
            except OSError:
                os.close(fd)
                continue
            self.lanes[name] = fd

    def dds(self, matched: int, now_ns: int, size: int) -> bool:
        """Whether a message of ``size`` bytes must go on DDS too
        (:meth:`~dcsms_ros.protocols.lanes.LaneTable.dds`), the lanes looked for again first
        when the DDS writer's ``matched`` count changed or :data:`REFRESH_S` passed
        (``now_ns``: monotonic ns)."""
        if matched != self._matched or now_ns >= self._due:
            self._matched = matched
            self._due = now_ns + int(REFRESH_S * 1e9)
            self.refresh()
        return self.table.dds(matched, len(self.lanes), size, self.outside)

    def write(self, data: bytes, t_ns: int) -> bool:
        """Write ``data``, published at ``t_ns`` (system clock ns), into every lane (never
        waits: a full lane loses it and counts it); False if it is too long for a lane (it
        must go on DDS)."""
        if len(data) > MAX_PAYLOAD:
            return False
        if not self.lanes:
            return True
        fr = frame(data, t_ns)
        gone = None
        for name, fd in self.lanes.items():
            try:
                os.write(fd, fr)
            except BlockingIOError:
                self.table.drop(name)
            except OSError as exc:
                if exc.errno not in (errno.EPIPE, errno.EBADF):
                    raise
                gone = [*(gone or []), name]
        self.table.sent += 1
        for name in gone or ():
            self._close(name, say_bye=False)
            self.left += 1
        return True

    def _close(self, name: str, say_bye: bool = True) -> None:
        fd = self.lanes.pop(name)
        if say_bye:
            with contextlib.suppress(OSError):
                os.write(fd, bye(self._pid))
        with contextlib.suppress(OSError):
            os.close(fd)

    def close(self) -> None:
        """Say bye on every lane and close them (idempotent)."""
        for name in list(self.lanes):
            self._close(name)


__all__ = ["ENV", "PIPE_SIZE", "REFRESH_S", "LaneReader", "LaneWriter", "enabled", "host_key",
           "lane_name", "lane_root", "pid_alive", "topic_dir"]
