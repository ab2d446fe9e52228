"""One topic of a bag as arrays: the value type, the chunk-by-chunk decoder that fills it, and
the column names and SI units of every exported component (:mod:`.reader` drives them)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from dcsms_ros import cdr
from dcsms_ros.analysis import mcapchunks
from dcsms_ros.errors import BagError

#: Twist components kept per body: x, y, z translations.
KEPT_AXES = (0, 1, 2)
AXIS_NAMES = ("x", "y", "z")
#: Columns of a kept wrench: force x y z (N), moment x y z (N*m).
WRENCH_AXES = ("x", "y", "z", "rx", "ry", "rz")


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
        Bag (receive) time of each row, ns, kept to place mode switches: the analysis keeps
        it for its reference topic, :func:`~.reader.read_topics` for every topic. In the
        rows' order, so not increasing where the stamps were reordered.
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


class TopicSink:
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
            vals, self.columns = all_columns(self.conn.msgtype, batch)
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
        if stamp.size > 1:
            # a lockstep retransmission repeats the sample just sent (same stamp, same
            # numbers): one sample, not two, for the estimators' uniform time axis; a
            # publisher whose stamps do not advance (left zero) sends new numbers each time,
            # and the stamp alone made 20,000 of them one row
            keep = np.empty(stamp.size, dtype=bool)
            keep[0] = True
            np.not_equal(stamp[1:], stamp[:-1], out=keep[1:])
            if not keep.all():
                keep[1:] |= (vals[1:] != vals[:-1]).any(axis=1)
            if not keep.all():
                stamp, vals = stamp[keep], vals[keep]
                log = None if log is None else log[keep]
        if stamp.size > 1 and np.any(np.diff(stamp) < 0):
            # Segmentation and alignment search the stamps: order them (a publisher that
            # reorders, or two recordings merged); each row keeps its own bag time
            order = np.argsort(stamp, kind="stable")
            stamp, vals = stamp[order], vals[order]
            log = None if log is None else log[order]
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


def all_columns(msgtype: str, batch: cdr.Batch) -> tuple[np.ndarray, tuple[str, ...]]:
    """Every component of a batch as float64 columns, and their names (:data:`TWIST_COLUMNS` …)."""
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


__all__ = ["AXIS_NAMES", "EXPORTABLE", "JOINT_UNITS", "KEPT_AXES", "TWIST_COLUMNS", "WRENCH_AXES",
           "WRENCH_COLUMNS", "TopicSeries", "TopicSink", "all_columns", "column_unit"]
