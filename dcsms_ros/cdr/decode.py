"""Numbers from serialized messages: one message on the control path, K messages from a bag.

Both read against the layouts of :mod:`.layout`. Per message (the nodes' 2 kHz path, raw
subscriptions) the stamp and the values are unpacked with :mod:`struct` at the layout's
offsets, without message objects (rclpy's conversion of a received TwistStamped costs more
than its numbers: take 16 -> 7 us). Per batch, K messages of one topic are one (K, R) byte
matrix and each field a column slice viewed as ``<f8`` (~50x faster than deserialising message
by message, which matters for an hour of 2 kHz data: 7.2 M messages per topic).

A batch's layout is read from its first message; if any message differs from it in a constant
byte (other size, frame_id, names, counts, a big-endian header) the batch falls back to rosbags'
``deserialize_cdr``, slow but always right. A single message the fast path does not recognise
(big-endian CDR, another layout than expected) goes the same way, so any well-formed publisher
works.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rosbags.typesys import Stores, get_typestore

# layout.X, but the per-message paths' names as plain globals (no attribute lookup per call)
from dcsms_ros.cdr import layout
from dcsms_ros.cdr.layout import (
    CDR_LE,
    FRAME_AT,
    NS,
    STAMP_AT,
    unpack_f8,
    unpack_f8x6,
    unpack_stamp,
    unpack_stamp_be,
    unpack_u32,
)

Array = NDArray[np.float64]
#: Where the characters of ``header.frame_id`` start (after their uint32 length).
_FRAME_TEXT = FRAME_AT + 4
#: Smallest message with a stamp, bytes.
_STAMP_END = STAMP_AT + 8
#: Types :func:`decode_batch` decodes.
BATCH_TYPES = (layout.TWIST_STAMPED, layout.WRENCH_STAMPED, layout.JOINT_STATE, layout.CLOCK)


@functools.cache
def typestore() -> Any:
    """The rosbags Jazzy typestore (created once; building it takes ~50 ms)."""
    return get_typestore(Stores.ROS2_JAZZY)


def deserialize(buf: bytes | memoryview, msgtype: str) -> Any:
    """One message as a rosbags object (any encapsulation rosbags reads).

    Raises
    ------
    ValueError
        ``buf`` is not a well-formed ``msgtype``.
    """
    try:
        return typestore().deserialize_cdr(bytes(buf), msgtype)
    except Exception as exc:  # noqa: BLE001 - rosbags raises several types for bad data
        raise ValueError(f"not a valid {msgtype} message: {type(exc).__name__}: {exc}") from None


def _time_ns(t: Any) -> int:
    return int(t.sec) * NS + int(t.nanosec)


# ---------------------------------------------------------------------------------------------
# Per message


def read_stamp(buf: bytes) -> int | None:
    """``header.stamp`` (or Clock's time) in ns of a message whose type starts with one;
    None if ``buf`` is not plain CDR (either byte order)."""
    # indexing, not slicing: called for every recorded message
    if len(buf) < _STAMP_END or buf[0]:
        return None
    if buf[1] == 1:  # 00 01: little endian
        sec, nsec = unpack_stamp(buf, STAMP_AT)
    elif buf[1] == 0:  # 00 00: big endian
        sec, nsec = unpack_stamp_be(buf, STAMP_AT)
    else:
        return None
    return sec * NS + nsec


#: Stamped vector messages by frame_id length (bytes with the NUL) -> (offset of the vector,
#: smallest message): the offsets depend on the length only, so they are taken from the layout
#: once per length (bounded: a topic's frame_id has one).
_VECTOR_AT: dict[int, tuple[int, int]] = {}


def _vector_at(n: int, length: int) -> tuple[int, int]:
    if n < 1 or n > length - _FRAME_TEXT:
        return 0, length + 1  # not a string: no message of this length fits
    lay = layout.message_layout(layout.TWIST_STAMPED, "x" * (n - 1))
    got = lay.fields["twist"][0], lay.size
    if len(_VECTOR_AT) < 64:
        _VECTOR_AT[n] = got
    return got


def read_stamped(buf: bytes, msgtype: str, dof: int) -> tuple[int, Array]:
    """Stamp and vector of a serialized TwistStamped or WrenchStamped.

    Parameters
    ----------
    buf : bytes
        The message as received (raw subscription).
    msgtype : str
        :data:`~.layout.TWIST_STAMPED` or :data:`~.layout.WRENCH_STAMPED`.
    dof : int
        1 (keep ``z`` / ``force.z``) or 6 (``x y z rx ry rz``).

    Returns
    -------
    stamp : int
        ``header.stamp`` in ns.
    v : ndarray of float64, shape (dof,)
        m/s and rad/s, or N and N*m.

    Raises
    ------
    ValueError
        Neither the fast path nor rosbags (big-endian CDR) can read ``buf``.
    """
    ns, v = read_stamped_floats(buf, msgtype, dof)
    return ns, np.array(v)


def read_stamped_floats(buf: bytes, msgtype: str, dof: int) -> tuple[int, tuple[float, ...]]:
    """:func:`read_stamped` with the vector as Python floats (a controller's sample stays on
    floats from its message to its message: :meth:`.controllers.FeedbackLoop.step_floats`)."""
    if buf[:2] == CDR_LE and len(buf) >= _FRAME_TEXT:
        n = unpack_u32(buf, FRAME_AT)[0]
        off, size = _VECTOR_AT.get(n) or _vector_at(n, len(buf))
        if len(buf) >= size:
            sec, nsec = unpack_stamp(buf, STAMP_AT)
            if dof == 1:
                return sec * NS + nsec, unpack_f8(buf, off + 16)  # z
            return sec * NS + nsec, unpack_f8x6(buf, off)
    m = deserialize(buf, msgtype)
    a, b = (m.twist.linear, m.twist.angular) if msgtype == layout.TWIST_STAMPED else \
        (m.wrench.force, m.wrench.torque)
    v = (a.z,) if dof == 1 else (a.x, a.y, a.z, b.x, b.y, b.z)
    return _time_ns(m.header.stamp), tuple(float(f) for f in v)


def read_header(buf: bytes, msgtype: str = layout.HEADER) -> tuple[int, str]:
    """(stamp ns, frame_id) of a serialized std_msgs/Header, or of the header a message of
    ``msgtype`` starts with."""
    if buf[:2] == CDR_LE and len(buf) >= _FRAME_TEXT:
        n = unpack_u32(buf, FRAME_AT)[0]
        if 1 <= n <= len(buf) - _FRAME_TEXT:
            sec, nsec = unpack_stamp(buf, STAMP_AT)
            return sec * NS + nsec, buf[_FRAME_TEXT:_FRAME_TEXT + n - 1].decode(
                errors="replace")
    m = deserialize(buf, msgtype)
    h = m if msgtype == layout.HEADER else m.header
    return _time_ns(h.stamp), str(h.frame_id)


def read_frame(buf: bytes, msgtype: str) -> str:
    """``header.frame_id`` of a serialized message of ``msgtype`` (one with a header)."""
    return read_header(buf, msgtype)[1]


class JointStateReader:
    """Read serialized JointStates: stamp, names and one field's values.

    The layout of the last message is kept; a message with the same constant bytes (the
    common case: one publisher with fixed names) is read at its offsets, and :meth:`read`
    returns that layout's own ``names`` tuple (the same object each time, so a caller can
    recognise the names by identity). Another layout is read from the message and kept.

    Parameters
    ----------
    field : {"velocity", "effort", "position"}
        The sequence whose values are returned.
    """

    def __init__(self, field: str = "velocity") -> None:
        self.field = field
        self._lay: layout.Layout | None = None
        self._at = self._n = 0

    def read(self, buf: bytes) -> tuple[int, tuple[str, ...], Array]:
        """(stamp ns, names, values (n,) float64) of one message; values are empty when the
        field is."""
        lay = self._lay
        if lay is None or not lay.matches(buf):
            try:
                lay = layout.read_layout(layout.JOINT_STATE, buf)
            except ValueError:  # big-endian or malformed: rosbags judges it
                m = deserialize(buf, layout.JOINT_STATE)
                return (_time_ns(m.header.stamp), tuple(m.name),
                        np.asarray(getattr(m, self.field), dtype=np.float64))
            self._lay = lay
            self._at, _, self._n = lay.fields[self.field]
        sec, nsec = unpack_stamp(buf, STAMP_AT)
        v = (np.frombuffer(buf, "<f8", self._n, self._at).astype(np.float64) if self._n
             else np.zeros(0))
        return sec * NS + nsec, lay.names, v


def decode_string(buf: bytes | memoryview) -> str:
    """Deserialise one std_msgs/String (rosbags for big-endian data)."""
    try:
        return layout.read_layout(layout.STRING, bytes(buf)).strings[0]
    except ValueError:
        return str(deserialize(buf, layout.STRING).data)


# ---------------------------------------------------------------------------------------------
# Batches


@dataclass
class Batch:
    """K decoded messages of one topic.

    Attributes
    ----------
    stamp_ns : ndarray of int64, shape (K,)
        ``header.stamp`` (or the Clock time) in ns.
    fields : dict of str to ndarray of float64
        ``twist`` / ``wrench``: (K, 6) as ``[x y z rx ry rz]``; JointState: ``position``,
        ``velocity``, ``effort``: (K, n) (n = 0 for an empty sequence).
    frame_id : str
        ``header.frame_id`` of the first message.
    names : tuple of str
        JointState ``name`` of the first message.
    fast : bool
        True when the numpy path decoded the batch, False after a fallback.
    """

    stamp_ns: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    frame_id: str = ""
    names: tuple[str, ...] = ()
    fast: bool = True


def decode_batch(msgtype: str, buffers: Sequence[bytes | memoryview]) -> Batch:
    """Decode K messages of one topic into arrays (numpy fast path, rosbags fallback).

    Parameters
    ----------
    msgtype : str
        One of :data:`BATCH_TYPES`.
    buffers : sequence of bytes, length K
        Raw CDR messages as stored in the bag.

    Returns
    -------
    Batch
        Stamps (K,) in ns and the numeric fields; see :class:`Batch`.
    """
    _check_type(msgtype)
    k = len(buffers)
    if k == 0:
        return _empty(msgtype)
    first = bytes(buffers[0])
    try:
        lay = layout.read_layout(msgtype, first)
    except ValueError:
        return _slow(msgtype, buffers)
    r = len(first)
    lengths = np.fromiter((len(b) for b in buffers), dtype=np.int64, count=k)
    if np.any(lengths != r):
        return _slow(msgtype, buffers)
    rows = np.frombuffer(b"".join(buffers), dtype=np.uint8).reshape(k, r)
    return _decode_rows(msgtype, rows, lay)


class BatchReader:
    """:func:`decode_batch` for a stream read in many small batches (a node draining its
    queue): the layout of the last batch is kept, so a batch from the same publisher costs
    the byte matrix and the column views only (measured: 100 TwistStamped in ~60 us against
    ~100 us for :func:`decode_batch` and ~250 us message by message).

    Parameters
    ----------
    msgtype : str
        One of :data:`BATCH_TYPES`.
    """

    def __init__(self, msgtype: str) -> None:
        _check_type(msgtype)
        self.msgtype = msgtype
        self._lay: layout.Layout | None = None

    def read(self, buffers: Sequence[bytes | memoryview]) -> Batch:
        """The batch of ``buffers`` (as :func:`decode_batch`)."""
        k = len(buffers)
        if k == 0:
            return _empty(self.msgtype)
        lay = self._lay
        sizes = set(map(len, buffers))  # ~10x cheaper than a generator over the buffers
        if lay is None or sizes != {lay.size}:
            try:
                lay = layout.read_layout(self.msgtype, bytes(buffers[0]))
            except ValueError:
                return _slow(self.msgtype, buffers)
            if sizes != {lay.size}:
                return _slow(self.msgtype, buffers)
            self._lay = lay
        rows = np.frombuffer(b"".join(buffers), dtype=np.uint8).reshape(k, lay.size)
        batch = _decode_rows(self.msgtype, rows, lay)
        if not batch.fast:
            self._lay = None  # another publisher's constant bytes: read its layout next time
        return batch


def decode_rows(msgtype: str, rows: np.ndarray) -> Batch:
    """Decode K same-size messages given as one (K, R) uint8 matrix (no per-message bytes).

    Same result as :func:`decode_batch` over the K rows (including its fallback when a row
    does not match the first one's layout).
    """
    _check_type(msgtype)
    if rows.shape[0] == 0:
        return _empty(msgtype)
    try:
        lay = layout.read_layout(msgtype, rows[0].tobytes())
    except ValueError:
        return _slow(msgtype, [row.tobytes() for row in rows])
    return _decode_rows(msgtype, rows, lay)


def _check_type(msgtype: str) -> None:
    if msgtype not in BATCH_TYPES:
        raise ValueError(f"no batch decoder for {msgtype}")


#: The stamp's fields of a layout, read into :attr:`Batch.stamp_ns`.
_STAMP_FIELDS = ("sec", "nanosec")


def _decode_rows(msgtype: str, rows: np.ndarray, lay: layout.Layout) -> Batch:
    # few numpy calls: a mode switch decodes its four streams once per checkpoint, cold
    # (array_equal and a column copy per field took ~50 us a batch there, docs/performance.md)
    if (rows[:, lay.const_idx] != lay.const_bytes).any():
        return _slow(msgtype, [row.tobytes() for row in rows])
    rec = np.ascontiguousarray(rows[:, :lay.size]).view(lay.record)[:, 0]  # trailing bytes
    stamp = rec["sec"][:, 0].astype(np.int64) * NS + rec["nanosec"][:, 0]
    cols = {n: rec[n].astype(np.float64) for n in lay.fields if n not in _STAMP_FIELDS}
    return Batch(stamp, cols, lay.frame_id, lay.names, True)


def _empty(msgtype: str) -> Batch:
    if msgtype in layout.VECTOR_FIELD:
        return Batch(np.zeros(0, np.int64), {layout.VECTOR_FIELD[msgtype]: np.zeros((0, 6))})
    if msgtype == layout.JOINT_STATE:
        return Batch(np.zeros(0, np.int64), {f: np.zeros((0, 0)) for f in layout.JOINT_FIELDS})
    return Batch(np.zeros(0, np.int64))


def _slow(msgtype: str, buffers: Sequence[bytes | memoryview]) -> Batch:
    """rosbags, message by message; JointState rows must still have one channel count."""
    ts = typestore()
    msgs = [ts.deserialize_cdr(bytes(b), msgtype) for b in buffers]
    if msgtype == layout.CLOCK:
        return Batch(np.asarray([_time_ns(m.clock) for m in msgs], np.int64), fast=False)
    stamp = np.asarray([_time_ns(m.header.stamp) for m in msgs], np.int64)
    frame_id = str(msgs[0].header.frame_id)
    if msgtype in layout.VECTOR_FIELD:
        if msgtype == layout.TWIST_STAMPED:
            vecs = [(m.twist.linear, m.twist.angular) for m in msgs]
        else:
            vecs = [(m.wrench.force, m.wrench.torque) for m in msgs]
        arr = np.array([[a.x, a.y, a.z, b.x, b.y, b.z] for a, b in vecs], dtype=np.float64)
        return Batch(stamp, {layout.VECTOR_FIELD[msgtype]: arr}, frame_id, (), False)
    cols = {}
    for f in layout.JOINT_FIELDS:
        n = max(len(getattr(m, f)) for m in msgs)
        # A message with a different channel count cannot share the array: pad with NaN.
        arr = np.full((len(msgs), n), np.nan)
        for i, m in enumerate(msgs):
            v = np.asarray(getattr(m, f), dtype=np.float64)
            arr[i, :v.size] = v
        cols[f] = arr
    return Batch(stamp, cols, frame_id, tuple(msgs[0].name), False)


__all__ = ["BATCH_TYPES", "Batch", "BatchReader", "JointStateReader", "decode_batch", "decode_rows",
           "decode_string", "deserialize", "read_frame", "read_header", "read_stamp",
           "read_stamped", "read_stamped_floats", "typestore"]
