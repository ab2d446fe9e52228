"""Read a DCSMS bag into per-topic arrays, streaming in chunks with bounded memory.

Only what the analysis needs is kept: the decoupled velocities ``/dcsms/velocity/<body>``
(or ``/dcsms/truth/<body>`` when a bag has no decoupled ones), the applied actuator forces, the
excitation wrench (``/dcsms/force/excitation``), the mode timeline and the recorded
configuration. Values are kept as float32 (velocities of
~1e-6 m/s keep 7 significant digits, far below any estimator's variance) and twists only as
x, y, z, so an hour at 2 kHz needs ~0.6 GB (1-DOF, 2 stages) to ~0.8 GB (6-DOF, 8 coils)
by arithmetic (20 B per velocity sample, 8 B + 4 B per force channel); `make bench` measures a
real one-hour 1-DOF recording: 854 MB peak for the whole `analyze`, imports included.
Arrays are preallocated from the message counts in the metadata, so no concatenation doubles
the peak.

A bag that cannot be opened or is truncated raises :class:`BagError` naming the file: a
partial analysis of a cut-off run would silently drop the last modes, which is worse than a
clear error (``ros2 bag reindex`` repairs a bag whose metadata was lost).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from fnmatch import fnmatch
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis import mcapchunks
from dcsms_ros.core import topics
from dcsms_ros.core.config import (
    SystemConfig,
    config_from_flat,
    params_text,
    parse_params_text,
)
from dcsms_ros.errors import BagError, ConfigError

#: std_msgs/String holding the flat parameters as YAML (published latched by the graph and
#: written by the batch engine) so an analysis can rebuild the analytic model.
CONFIG_TOPIC = topics.CONFIG
#: Twist components kept per body: x, y, z translations.
KEPT_AXES = (0, 1, 2)
AXIS_NAMES = ("x", "y", "z")
#: Columns of a kept wrench: force x y z (N), moment x y z (N*m).
WRENCH_AXES = ("x", "y", "z", "rx", "ry", "rz")
_BODY_TOPIC = re.compile(r"^/dcsms/(velocity|truth)/(ground|stage\d+)$")

Progress = Callable[[int, int], None]


@dataclass
class TopicSeries:
    """One topic as arrays.

    Attributes
    ----------
    topic, msgtype : str
    stamp_ns : ndarray of int64, shape (K,)
        Header stamps (ns).
    values : ndarray of float32, shape (K, n)
        Twist x, y, z (m/s), wrench x y z rx ry rz (N, N*m) or JointState effort (N), one
        column per channel.
    columns : tuple of str
        Names of the n columns (``x y z``, ``x y z rx ry rz`` or joint names).
    frame_id : str
    log_ns : ndarray of int64, shape (K,) or None
        Bag (receive) time; kept for the reference topic only, to place mode switches.
    """

    topic: str
    msgtype: str
    stamp_ns: np.ndarray
    values: np.ndarray
    columns: tuple[str, ...] = ()
    frame_id: str = ""
    log_ns: np.ndarray | None = None

    @property
    def stamp_s(self) -> np.ndarray:
        """Header stamps in s relative to nothing (epoch or sim time), float64, shape (K,)."""
        return self.stamp_ns.astype(np.float64) * 1e-9


@dataclass
class ModeEvent:
    """A mode switch: its bag time, the header-stamp time it maps to and its label."""

    log_ns: int
    stamp_ns: int
    label: str


@dataclass
class BagData:
    """Everything :func:`read_bag` extracts from one bag."""

    path: Path
    bodies: dict[str, TopicSeries] = field(default_factory=dict)  # body name -> velocity
    applied: TopicSeries | None = None
    excitation: TopicSeries | None = None  # frame_id: the excited stage
    modes: list[ModeEvent] = field(default_factory=list)
    config_text: str | None = None
    source: str = "velocity"  # or "truth"
    warnings: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)  # all topics in the bag


def config_to_yaml(cfg: SystemConfig) -> str:
    """``cfg`` as the text of ``/dcsms/config``: a ROS 2 params file (see ``params_text``)."""
    return params_text(cfg.params or {})


def config_from_yaml(text: str, source: str = "/dcsms/config") -> SystemConfig:
    """Rebuild a :class:`SystemConfig` from ``/dcsms/config`` text: a params file, or a plain
    ``{dotted: value}`` mapping (bags written before the params-file form).

    Raises
    ------
    ConfigError
        If the text is not YAML of either form or a value is invalid; names ``source``.
    """
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: invalid YAML: {exc}") from None
    if not isinstance(doc, dict):
        raise ConfigError(f"{source}: expected a ROS 2 params file or a mapping of dotted names")
    if doc and all(isinstance(v, dict) and "ros__parameters" in v for v in doc.values()):
        return config_from_flat(parse_params_text(text, source), source)
    return config_from_flat(doc, source)


def read_bag(path: str | Path, progress: Progress | None = None,
             chunk: int = 50_000) -> BagData:
    """Read the analysis topics of one bag.

    Parameters
    ----------
    path : str or Path
        rosbag2 directory (or a bare ``.mcap``/``.db3`` file).
    progress : callable(done, total), optional
        Called after every chunk with messages read so far and the total in the bag.
    chunk : int
        Messages per topic decoded at once (bounds the raw-buffer memory).

    Raises
    ------
    BagError
        If the bag is missing, unreadable, truncated or holds no velocity topics.
    """
    p = Path(path)
    return _with_reader(p, lambda reader: _read(reader, p, progress, chunk))


def _with_reader(p: Path, work: Callable[[Any], Any]) -> Any:
    """``work(reader)`` on an open rosbags Reader of ``p``; every failure but a BagError
    becomes one BagError naming the file."""
    if not p.exists():
        raise BagError(f"{p}: no such bag")
    try:
        with Reader(p) as reader:
            return work(reader)
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags/mcap/sqlite raise many types
        detail = " ".join(str(exc).split())  # one line: YAML errors span several
        raise BagError(f"{p}: cannot read bag (truncated or corrupted?): "
                       f"{type(exc).__name__}: {detail}") from None


def _read(reader: Any, path: Path, progress: Progress | None, chunk: int) -> BagData:
    data = BagData(path)
    conns = list(reader.connections)
    data.counts = {}
    for c in conns:
        data.counts[c.topic] = data.counts.get(c.topic, 0) + c.msgcount
    body_conns: dict[str, dict[str, Any]] = {"velocity": {}, "truth": {}}
    for c in conns:
        m = _BODY_TOPIC.match(c.topic)
        if m and c.msgtype == cdr.TWIST_STAMPED:
            body_conns[m.group(1)][m.group(2)] = c
    data.source = "velocity" if body_conns["velocity"] else "truth"
    chosen = body_conns[data.source]
    if not chosen:
        raise BagError(f"{path}: no /dcsms/velocity/* or /dcsms/truth/* TwistStamped topics "
                       f"(topics: {', '.join(sorted(data.counts)) or 'none'})")
    if data.source == "truth":
        data.warnings.append("no decoupled /dcsms/velocity/* topics: using /dcsms/truth/*")
    ref_body = "ground" if "ground" in chosen else min(chosen)
    wanted = {c.topic: c for c in chosen.values()}
    for c in conns:
        applied = c.topic == topics.ACTUATORS_APPLIED and c.msgtype == cdr.JOINT_STATE
        excite = c.topic == topics.EXCITATION and c.msgtype == cdr.WRENCH_STAMPED
        text = c.topic in (topics.MODE, CONFIG_TOPIC) and c.msgtype == cdr.STRING
        if applied or excite or text:
            wanted[c.topic] = c
    sinks = {t: _Sink(c, keep_log=(t == chosen[ref_body].topic))
             for t, c in wanted.items() if c.msgtype != cdr.STRING}
    total = sum(c.msgcount for c in wanted.values())
    mode_log: list[tuple[int, str]] = []

    def on_text(conn: Any, t_ns: int, raw: bytes | np.ndarray) -> None:
        value = cdr.decode_string(bytes(raw))
        if conn.topic == topics.MODE:
            mode_log.append((t_ns, value.strip()))
        elif data.config_text is None:
            data.config_text = value

    if not _read_chunks(reader, wanted, sinks, on_text, progress, total):
        mode_log.clear()
        sinks = {t: _Sink(s.conn, s.keep_log) for t, s in sinks.items()}
        _read_messages(reader, wanted, sinks, on_text, progress, total, chunk)
    if progress is not None:
        progress(total, total)
    for body, c in chosen.items():
        data.bodies[body] = sinks[c.topic].result()
    if topics.ACTUATORS_APPLIED in sinks:
        data.applied = sinks[topics.ACTUATORS_APPLIED].result()
    if topics.EXCITATION in sinks:
        data.excitation = sinks[topics.EXCITATION].result()
    data.modes = _place_modes(mode_log, data.bodies[ref_body])
    for s in sinks.values():
        if s.fallback:
            data.warnings.append(f"{s.conn.topic}: {s.fallback} chunk(s) decoded by the slow "
                                 "path (layout changed between messages)")
    return data


def _mcap_files(reader: Any) -> list[Path] | None:
    """The storage files when every one is MCAP (rosbags reader internals, checked)."""
    storages = getattr(reader.storage, "storages", [reader.storage])
    paths = [getattr(s, "path", None) for s in storages]
    if not paths or not all(isinstance(p, Path) and p.suffix == ".mcap" for p in paths):
        return None
    return [p for p in paths if isinstance(p, Path)]


def _read_chunks(reader: Any, wanted: dict[str, Any], sinks: dict[str, _Sink],
                 text: Callable[[Any, int, Any], None], progress: Progress | None,
                 total: int) -> bool:
    """Fast path: whole MCAP chunks as byte matrices (:mod:`.mcapchunks`). False when the
    files need the rosbags reader (not MCAP, unindexed, unknown compression, or a topic whose
    messages are out of log-time order across chunks); nothing is kept from a False run."""
    files = _mcap_files(reader)
    if files is None:
        return False
    done = 0

    def tick(n: int) -> None:
        nonlocal done
        done += n
        if progress is not None:
            progress(done, total)

    try:
        for f in files:
            chans, chunks = mcapchunks.summary(f)
            ids = {cid: wanted[t] for cid, (t, schema) in chans.items()
                   if t in wanted and schema == wanted[t].msgtype}
            for block in mcapchunks.iter_blocks(f, set(ids), chunks, tick):
                conn = ids[block.channel]
                if conn.msgtype != cdr.STRING:
                    if not sinks[conn.topic].add_block(block):
                        return False
                    continue
                payloads: Any = block.rows if block.rows is not None else block.buffers
                for t_ns, raw in zip(block.log_ns.tolist(), payloads, strict=True):
                    text(conn, t_ns, raw)
    except mcapchunks.Unsupported:
        return False
    return True


def _read_messages(reader: Any, wanted: dict[str, Any], sinks: dict[str, _Sink],
                   text: Callable[[Any, int, Any], None], progress: Progress | None,
                   total: int, chunk: int) -> None:
    """rosbags path: message by message (SQLite 3 bags, unindexed MCAP)."""
    done = 0
    for conn, t_ns, raw in reader.messages(connections=list(wanted.values())):
        if conn.msgtype == cdr.STRING:
            text(conn, t_ns, raw)
            continue
        sink = sinks[conn.topic]
        sink.add(t_ns, raw)
        if len(sink.raw) >= chunk:
            sink.flush()
            done += chunk
            if progress is not None:
                progress(done, total)
    for sink in sinks.values():
        sink.flush()


class _Sink:
    """Buffers one topic's raw messages and decodes them chunk by chunk into arrays."""

    def __init__(self, conn: Any, keep_log: bool, full: bool = False) -> None:
        self.conn = conn
        self.full = full  # every component as float64 (read_topics), not the analysis subset
        self.raw: list[bytes] = []
        self.log: list[int] = []
        self.keep_log = keep_log
        n = max(int(conn.msgcount), 0)
        self.stamp = np.empty(n, np.int64)
        self.values: np.ndarray | None = None
        self.log_ns = np.empty(n, np.int64) if keep_log else None
        self.k = 0
        self.columns: tuple[str, ...] = ()
        self.frame_id = ""
        self.fallback = 0
        self.last_log = -(2**63)

    def add(self, t_ns: int, raw: bytes) -> None:
        self.raw.append(raw)
        if self.keep_log:
            self.log.append(t_ns)

    def add_block(self, block: mcapchunks.Block) -> bool:
        """Decode one chunk's messages of this topic; False if they arrive out of log-time
        order relative to earlier chunks (rosbags would interleave them: use its path)."""
        if len(block) == 0:
            return True
        if int(block.log_ns[0]) < self.last_log:
            return False
        self.last_log = int(block.log_ns[-1])
        if block.rows is not None:
            batch = cdr.decode_rows(self.conn.msgtype, block.rows)
        else:
            batch = cdr.decode_batch(self.conn.msgtype, block.buffers or [])
        self._store(batch, block.log_ns)
        return True

    def flush(self) -> None:
        if not self.raw:
            return
        self._store(cdr.decode_batch(self.conn.msgtype, self.raw), self.log)
        self.raw.clear()
        self.log.clear()

    def _store(self, batch: cdr.Batch, log: Any) -> None:
        self.fallback += not batch.fast
        if self.full:
            vals, self.columns = _all_columns(self.conn.msgtype, batch)
        elif self.conn.msgtype == cdr.TWIST_STAMPED:
            vals = batch.fields["twist"][:, KEPT_AXES]
            self.columns = AXIS_NAMES
        elif self.conn.msgtype == cdr.WRENCH_STAMPED:
            vals = batch.fields["wrench"]
            self.columns = WRENCH_AXES
        else:
            vals = batch.fields["effort"]
            self.columns = batch.names
        self.frame_id = batch.frame_id
        k = batch.stamp_ns.size
        self._ensure(self.k + k, vals.shape[1])
        assert self.values is not None
        if vals.shape[1] != self.values.shape[1]:
            raise BagError(f"{self.conn.topic}: channel count changed from "
                           f"{self.values.shape[1]} to {vals.shape[1]}")
        self.stamp[self.k:self.k + k] = batch.stamp_ns
        self.values[self.k:self.k + k] = vals
        if self.log_ns is not None:
            self.log_ns[self.k:self.k + k] = log
        self.k += k

    def _ensure(self, n: int, width: int) -> None:
        if self.values is None:
            self.values = np.empty((self.stamp.size, width),
                                   np.float64 if self.full else np.float32)
        if n > self.stamp.size:  # metadata under-counted: grow geometrically
            size = max(n, 2 * self.stamp.size)
            self.stamp = np.resize(self.stamp, size)
            self.values = np.resize(self.values, (size, self.values.shape[1]))
            if self.log_ns is not None:
                self.log_ns = np.resize(self.log_ns, size)

    def result(self) -> TopicSeries:
        vals = self.values if self.values is not None else np.zeros((0, 0), np.float32)
        stamp, vals = self.stamp[:self.k], vals[:self.k]
        log = None if self.log_ns is None else self.log_ns[:self.k]
        if stamp.size > 1 and np.any(np.diff(stamp) < 0):
            # Segmentation and alignment search the stamps: order them (a publisher that
            # reorders, or two recordings merged); the bag times keep their own order.
            order = np.argsort(stamp, kind="stable")
            stamp, vals = stamp[order], vals[order]
        return TopicSeries(self.conn.topic, self.conn.msgtype, stamp, vals, self.columns,
                           self.frame_id, log)


#: Column names of every component (:func:`read_topics`), SI units.
TWIST_COLUMNS = (("vx", "m/s"), ("vy", "m/s"), ("vz", "m/s"), ("wx", "rad/s"), ("wy", "rad/s"),
                 ("wz", "rad/s"))
WRENCH_COLUMNS = (("fx", "N"), ("fy", "N"), ("fz", "N"), ("mx", "N*m"), ("my", "N*m"),
                  ("mz", "N*m"))
#: Units of the JointState fields the graph fills (velocity: geophone channels, effort: forces).
JOINT_UNITS = {"position": "m", "velocity": "m/s", "effort": "N"}
#: Message types :func:`read_topics` exports.
EXPORTABLE = (cdr.TWIST_STAMPED, cdr.WRENCH_STAMPED, cdr.JOINT_STATE)


def _all_columns(msgtype: str, batch: cdr.Batch) -> tuple[np.ndarray, tuple[str, ...]]:
    if msgtype == cdr.TWIST_STAMPED:
        return batch.fields["twist"], tuple(c for c, _ in TWIST_COLUMNS)
    if msgtype == cdr.WRENCH_STAMPED:
        return batch.fields["wrench"], tuple(c for c, _ in WRENCH_COLUMNS)
    parts, names = [], []
    for fld in ("position", "velocity", "effort"):
        v = batch.fields.get(fld)
        if v is not None and v.shape[1]:
            parts.append(v)
            names += [f"{fld}:{n}" for n in batch.names] if batch.names else [
                f"{fld}:{i}" for i in range(v.shape[1])]
    if not parts:
        return np.zeros((batch.stamp_ns.size, 0)), ()
    return np.hstack(parts), tuple(names)


def column_unit(msgtype: str, column: str) -> str:
    """SI unit of one :func:`read_topics` column."""
    for c, u in (*TWIST_COLUMNS, *WRENCH_COLUMNS):
        if c == column and msgtype in (cdr.TWIST_STAMPED, cdr.WRENCH_STAMPED):
            return u
    return JOINT_UNITS.get(column.partition(":")[0], "-")


def read_topics(path: str | Path, names: Iterable[str] | None = None,
                progress: Progress | None = None,
                strict: bool = True) -> tuple[dict[str, TopicSeries], list[tuple[int, str]]]:
    """Every component of the chosen topics at full precision (float64), and the mode log.

    Parameters
    ----------
    path : str or Path
        rosbag2 directory (or a bare ``.mcap``/``.db3`` file).
    names : iterable of str, optional
        Topics or ``fnmatch`` patterns (``/dcsms/velocity/*``); default: every TwistStamped,
        WrenchStamped and JointState topic under ``/dcsms``.
    progress : callable(done, total), optional
    strict : bool
        Every name must match a topic with numbers (else BagError); False skips those that
        match none.

    Returns
    -------
    series : dict of topic to TopicSeries
        Values (K, n) float64 in SI units; columns ``vx vy vz wx wy wz`` (m/s, rad/s),
        ``fx fy fz mx my mz`` (N, N*m), or ``<field>:<joint>`` (JointState).
    modes : list of (bag time ns, label)
        ``/dcsms/mode`` as recorded.

    Raises
    ------
    BagError
        Unreadable bag, a named topic that is missing, or one of a type without numbers.
    """
    p = Path(path)
    pats = list(names) if names is not None else ["/dcsms/*"]
    modes: list[tuple[int, str]] = []

    def on_text(conn: Any, t_ns: int, raw: bytes | np.ndarray) -> None:
        modes.append((t_ns, cdr.decode_string(bytes(raw)).strip()))

    def work(reader: Any) -> dict[str, TopicSeries]:
        conns = list(reader.connections)
        wanted: dict[str, Any] = {}
        for pat in pats:
            hit = [c for c in conns if fnmatch(c.topic, pat)]
            num = [c for c in hit if c.msgtype in EXPORTABLE]
            if names is not None and strict and not num:
                why = (f"type {hit[0].msgtype} has no numeric samples to export" if hit
                       else "no such topic")
                raise BagError(f"{p}: {pat}: {why} (topics: "
                               f"{', '.join(sorted({c.topic for c in conns}))})")
            wanted.update({c.topic: c for c in num})
        wanted.update({c.topic: c for c in conns
                       if c.topic == topics.MODE and c.msgtype == cdr.STRING})
        sinks = {t: _Sink(c, keep_log=False, full=True) for t, c in wanted.items()
                 if c.msgtype != cdr.STRING}
        total = sum(c.msgcount for c in wanted.values())
        if not _read_chunks(reader, wanted, sinks, on_text, progress, total):
            modes.clear()
            sinks = {t: _Sink(s.conn, False, full=True) for t, s in sinks.items()}
            _read_messages(reader, wanted, sinks, on_text, progress, total, 50_000)
        return {t: s.result() for t, s in sorted(sinks.items())}

    series = _with_reader(p, work)
    return series, sorted(modes)


def _place_modes(mode_log: Iterable[tuple[int, str]], ref: TopicSeries) -> list[ModeEvent]:
    """Map each switch's bag time to the header stamp of the first reference sample after it.

    String has no header, so a switch only has its bag (receive) time; when the recorder runs
    on wall time and the graph on sim time the two clocks differ, but the reference topic has
    both, which places the switch on the data's own time axis.
    """
    out: list[ModeEvent] = []
    log = ref.log_ns
    if log is None or log.size == 0:
        return out
    for t_ns, label in sorted(mode_log):
        i = int(np.searchsorted(log, t_ns, side="left"))
        if i >= log.size:
            continue  # switched after the last sample: no data in that mode
        if out and out[-1].label == label:
            continue  # a re-published (latched) label is not a switch
        out.append(ModeEvent(int(t_ns), int(ref.stamp_ns[i]), label))
    return out


__all__ = [
    "AXIS_NAMES", "CONFIG_TOPIC", "EXPORTABLE", "WRENCH_AXES", "BagData", "ModeEvent",
    "TopicSeries", "column_unit", "config_from_yaml", "config_to_yaml", "read_bag",
    "read_topics",
]
