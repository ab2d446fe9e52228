"""Serialise messages from numbers: one message on the control path, K messages for a bag.

Both fill the templates of :mod:`.layout`. Per message (the nodes' 2 kHz path) a writer packs
the template's constant pieces, the stamp and the values with one :mod:`struct` call (a copy
of the template packed in place took two calls and two copies more: 450 against 190 ns per
TwistStamped), and the node publishes the bytes: no message object is built (rclpy's objects
cost more than the numbers they carry, measured per TwistStamped: building it 5 us -> 1 us,
publishing 11.5 -> 7.3 us). Per batch, K messages are one (K, R) uint8 matrix whose columns are
written as numpy views, for the bag writers. The bytes equal rosbags' serialisation, and
rclpy's except for padding, which rmw leaves uninitialised (tested).

Units: stamps in integer ns; twists m/s and rad/s, wrenches N and N*m, JointState values as
the channel's unit (geophone velocity m/s, actuator force N).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

# layout.X, but the per-message paths' names as plain globals (no attribute lookup per call)
from dcsms_ros.cdr import layout
from dcsms_ros.cdr.decode import typestore
from dcsms_ros.cdr.layout import NS, STAMP_AT, pack_stamp

Array = NDArray[np.float64]


#: diagnostic_msgs/DiagnosticArray (:func:`encode_diagnostics`)
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"

# ---------------------------------------------------------------------------------------------
# Per message


class StampedWriter:
    """Serialise a TwistStamped or WrenchStamped of one ``frame`` from a (dof,) vector.

    Parameters
    ----------
    msgtype : str
        :data:`~.layout.TWIST_STAMPED` or :data:`~.layout.WRENCH_STAMPED`.
    frame : str
        ``header.frame_id``.
    dof : int
        1 (``z`` / ``force.z`` only, the rest zero) or 6 (``x y z rx ry rz``).
    """

    def __init__(self, msgtype: str, frame: str, dof: int) -> None:
        lay = layout.message_layout(msgtype, frame)
        self._pack, self._pre, self._mid, self._tail = _packer(lay, layout.VECTOR_FIELD[msgtype])
        self.dof = dof

    def encode(self, ns: int, v: Array | Sequence[float]) -> bytes:
        """CDR bytes of the message stamped ``ns`` (int ns) carrying ``v`` (dof,), an array or
        Python floats."""
        sec, nsec = divmod(ns, NS)
        if self.dof == 1:  # z: the third float64
            return self._pack(self._pre, sec, nsec, self._mid, 0.0, 0.0, v[0], 0.0, 0.0, 0.0,
                              self._tail)
        return self._pack(self._pre, sec, nsec, self._mid,
                          *(v.tolist() if isinstance(v, np.ndarray) else v)[:6], self._tail)


class JointStateWriter:
    """Serialise a JointState with fixed channel ``names`` and one filled ``field``.

    Parameters
    ----------
    names : sequence of str
        ``name``, n channels.
    field : {"velocity", "effort"}
        The array that carries the values (m/s or N); the other two are empty.
    """

    def __init__(self, names: Sequence[str], field: str) -> None:
        n = len(names)
        counts = (0, n, 0) if field == "velocity" else (0, 0, n)
        lay = layout.message_layout(layout.JOINT_STATE, "", names, counts)
        self._pack, self._pre, self._mid, self._tail = _packer(lay, field)

    def encode(self, ns: int, values: Array | Sequence[float]) -> bytes:
        """CDR bytes of the message stamped ``ns`` carrying ``values`` (n,), an array or
        Python floats (another count raises ``struct.error``)."""
        sec, nsec = divmod(ns, NS)
        return self._pack(self._pre, sec, nsec, self._mid,
                          *(values.tolist() if isinstance(values, np.ndarray) else values),
                          self._tail)


def _packer(lay: layout.Layout, field: str) -> tuple[Callable[..., bytes], bytes, bytes, bytes]:
    """One ``struct`` packer of a message of ``lay`` whose numbers are the stamp and the float64
    ``field``: ``pack(pre, sec, nanosec, mid, *values, tail)`` with the template's pieces
    around them (constant bytes and zero padding)."""
    at, (off, _, count) = lay.fields["sec"][0], lay.fields[field]
    assert lay.fields["nanosec"][0] == at + 4  # the stamp: int32 sec, uint32 nanosec
    pre, mid, tail = lay.buf[:at], lay.buf[at + 8:off], lay.buf[off + 8 * count:]
    fmt = f"<{len(pre)}siI{len(mid)}s{count}d{len(tail)}s"
    return struct.Struct(fmt).pack, pre, mid, tail


#: Header templates by frame_id (a few: the trip checkpoint's question and answers).
_HEADERS: dict[str, bytes] = {}


def header_bytes(ns: int, frame: str = "") -> bytes:
    """CDR bytes of a std_msgs/Header stamped ``ns`` (int ns) with ``frame``."""
    tpl = _HEADERS.get(frame)
    if tpl is None:
        tpl = layout.message_layout(layout.HEADER, frame).buf
        if len(_HEADERS) < 64:
            _HEADERS[frame] = tpl
    b = bytearray(tpl)
    pack_stamp(b, STAMP_AT, ns // NS, ns % NS)
    return bytes(b)


_CLOCK = layout.message_layout(layout.CLOCK).buf


def clock_bytes(ns: int) -> bytes:
    """CDR bytes of a rosgraph_msgs/Clock at ``ns`` (int ns). Without a message object a
    composed lockstep step that publishes /clock takes 18 us more than the others instead of
    34 (medians of 10 runs, docs/performance.md)."""
    b = bytearray(_CLOCK)
    pack_stamp(b, STAMP_AT, ns // NS, ns % NS)  # a Clock's time sits where a header's stamp does
    return bytes(b)


def encode_string(text: str) -> bytes:
    """Serialise one std_msgs/String."""
    return layout.build_layout(layout.STRING, (text,)).buf


#: One status of :func:`encode_diagnostics`: level (0 OK, 1 WARN, 2 ERROR, 3 STALE), name,
#: message, hardware_id and the key/value pairs (each value written as ``str(value)``).
DiagnosticStatus = tuple[int, str, str, str, Mapping[str, object]]


def encode_diagnostics(stamp_ns: int, statuses: Sequence[DiagnosticStatus]) -> bytes:
    """Serialise one diagnostic_msgs/DiagnosticArray stamped ``stamp_ns`` (int ns), in Python
    (rosbags' serialiser): unlike rclpy's conversion of a message object, one C call that held
    the GIL for ~185 us in the composed graph, it lets the process's real-time thread take the
    GIL every switch interval (:mod:`dcsms_ros.ros.gilfree`)."""
    ts = typestore()
    t = ts.types
    kv, status = t["diagnostic_msgs/msg/KeyValue"], t["diagnostic_msgs/msg/DiagnosticStatus"]
    msg = t[DIAGNOSTIC_ARRAY](
        header=t[layout.HEADER](stamp=t["builtin_interfaces/msg/Time"](
            sec=stamp_ns // NS, nanosec=stamp_ns % NS), frame_id=""),
        status=[status(level=level, name=name, message=message, hardware_id=hw,
                       values=[kv(key=k, value=str(v)) for k, v in values.items()])
                for level, name, message, hw, values in statuses])
    return bytes(ts.serialize_cdr(msg, DIAGNOSTIC_ARRAY))


# ---------------------------------------------------------------------------------------------
# Batches


def encode_rows(lay: layout.Layout, stamp_ns: ArrayLike, values: Mapping[str, ArrayLike],
                out: NDArray[np.uint8] | None = None) -> NDArray[np.uint8]:
    """K messages of one layout as a (K, R) uint8 matrix.

    Parameters
    ----------
    lay : layout.Layout
        The messages' layout (:func:`~.layout.message_layout`), R = ``lay.size`` bytes.
    stamp_ns : array_like of int, shape (K,)
        Header stamps (Clock: the time) in ns.
    values : mapping of str to array_like of float
        Each numeric field of ``lay`` but the stamp: (K, count) (a (count,) row is repeated);
        fields of count 0 may be left out.
    out : ndarray of uint8, shape (K, R), optional
        Where to write (e.g. columns of a bag's block of records), template included;
        a new matrix when None.

    Returns
    -------
    ndarray of uint8, shape (K, R)
        ``out`` or the new matrix.
    """
    sec, nsec = layout.split_ns(stamp_ns)
    k = sec.size
    if out is None:
        out = np.empty((k, lay.size), np.uint8)
        out[:] = lay.template
    vals = dict(values, sec=sec, nanosec=nsec)
    for name, (off, dtype, count) in lay.fields.items():
        if not count:
            continue
        v = np.asarray(vals[name])
        v = v.reshape(k, count) if v.size == k * count else np.broadcast_to(v, (k, count))
        col = np.ascontiguousarray(v, dtype=dtype)
        out[:, off:off + col.itemsize * count] = col.view(np.uint8).reshape(k, -1)
    return out


def _split(rows: NDArray[np.uint8]) -> list[bytes]:
    data, r = rows.tobytes(), rows.shape[1]
    return [data[i * r:(i + 1) * r] for i in range(rows.shape[0])]


def encode_stamped(msgtype: str, stamp_ns: NDArray[np.int64], frame_id: str,
                   values: NDArray[np.float64]) -> list[bytes]:
    """Serialise K TwistStamped or WrenchStamped messages.

    Parameters
    ----------
    msgtype : str
        :data:`~.layout.TWIST_STAMPED` or :data:`~.layout.WRENCH_STAMPED`.
    stamp_ns : array_like of int, shape (K,)
        Header stamps in ns.
    frame_id : str
        Header frame_id of every message.
    values : array_like of float, shape (K, 6)
        ``[vx vy vz wx wy wz]`` (m/s, rad/s) or ``[fx fy fz mx my mz]`` (N, N*m).

    Returns
    -------
    list of bytes
        K CDR buffers with the encapsulation header, byte-identical to rosbags'.
    """
    v = np.asarray(values, dtype=np.float64)
    k = np.asarray(stamp_ns).size
    if v.shape != (k, 6):
        raise ValueError(f"values must have shape ({k}, 6), got {v.shape}")
    return _split(encode_rows(layout.message_layout(msgtype, frame_id), stamp_ns,
                              {layout.VECTOR_FIELD[msgtype]: v}))


def encode_joint_state(stamp_ns: NDArray[np.int64], frame_id: str, names: Sequence[str],
                       position: NDArray[np.float64] | None = None,
                       velocity: NDArray[np.float64] | None = None,
                       effort: NDArray[np.float64] | None = None) -> list[bytes]:
    """Serialise K sensor_msgs/JointState messages with fixed names.

    Parameters
    ----------
    stamp_ns : array_like of int, shape (K,)
        Header stamps in ns.
    frame_id : str
        Header frame_id.
    names : sequence of str, length n
        Channel names (``name``).
    position, velocity, effort : array_like of float, shape (K, n), optional
        None gives an empty sequence (the usual way to omit a field).
    """
    k = np.asarray(stamp_ns).size
    arrays, counts = {}, []
    for name, arr in zip(layout.JOINT_FIELDS, (position, velocity, effort), strict=True):
        a = np.zeros((k, 0)) if arr is None else np.asarray(arr, np.float64).reshape(k, -1)
        counts.append(a.shape[1])
        arrays[name] = a
    lay = layout.message_layout(layout.JOINT_STATE, frame_id, names, counts)
    return _split(encode_rows(lay, stamp_ns, arrays))


def encode_clock(stamp_ns: NDArray[np.int64]) -> list[bytes]:
    """Serialise K rosgraph_msgs/Clock messages from times in ns, shape (K,)."""
    return _split(encode_rows(layout.message_layout(layout.CLOCK), stamp_ns, {}))


__all__ = ["DIAGNOSTIC_ARRAY", "DiagnosticStatus", "JointStateWriter", "StampedWriter",
           "clock_bytes", "encode_clock", "encode_diagnostics", "encode_joint_state",
           "encode_rows", "encode_stamped", "encode_string", "header_bytes"]
