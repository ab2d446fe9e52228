"""Per-message CDR on the control path: serialized bytes in, serialized bytes out.

rclpy converts every received message into Python objects (a TwistStamped is seven of them) and
every published one back into C structs; on the 2 kHz path that conversion costs more than the
numbers it carries (measured: take 16 -> 7 us, publish 11.5 -> 7.3 us, building the message
5 us -> 1 us per TwistStamped). The hot-path subscriptions are therefore ``raw`` and the
per-sample publications are bytes, encoded and decoded here with :mod:`struct` against the byte
templates of :mod:`dcsms_ros.analysis.cdr` (same format, tested against rclpy's own
serialization). A message this fast path does not recognise (big-endian CDR, truncated)
goes through ``rclpy.serialization.deserialize_message``, so any well-formed publisher works.

Units as in :mod:`.msgs`: m/s, rad/s, N, N*m; stamps in integer ns.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import TwistStamped, WrenchStamped
from numpy.typing import NDArray
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from dcsms_ros.analysis import cdr
from dcsms_ros.nodes.msgs import NS, stamp_ns

Array = NDArray[np.float64]
_LE = b"\x00\x01"
_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_D = struct.Struct("<d")
_D6 = struct.Struct("<6d")
_TYPES = {TwistStamped: cdr.TWIST_STAMPED, WrenchStamped: cdr.WRENCH_STAMPED}


class StampedWriter:
    """Serialise a TwistStamped or WrenchStamped of one ``frame`` from a (dof,) vector.

    Parameters
    ----------
    msg_type : type
        ``TwistStamped`` or ``WrenchStamped``.
    frame : str
        ``header.frame_id``.
    dof : int
        1 (``z`` / ``force.z`` only, the rest zero) or 6 (``x y z rx ry rz``).
    """

    def __init__(self, msg_type: Any, frame: str, dof: int) -> None:
        lay = cdr.message_layout(_TYPES[msg_type], frame)
        self._template = bytes(lay.buf)
        self._off = next(iter(v[0] for k, v in lay.fields.items() if k in ("twist", "wrench")))
        self.dof = dof

    def encode(self, ns: int, v: Array) -> bytes:
        """CDR bytes of the message stamped ``ns`` (int ns) carrying ``v``."""
        b = bytearray(self._template)
        _STAMP.pack_into(b, 4, ns // NS, ns % NS)
        if self.dof == 1:
            _D.pack_into(b, self._off + 16, float(v[0]))
        else:
            _D6.pack_into(b, self._off, *(float(x) for x in v[:6]))
        return bytes(b)


def read_stamped(buf: bytes, msg_type: Any, dof: int) -> tuple[int, Array]:
    """(stamp ns, (dof,) vector) of a serialized TwistStamped/WrenchStamped; 1dof keeps z."""
    if buf[:2] == _LE and len(buf) >= 16:
        n = _U32.unpack_from(buf, 12)[0]
        off = 16 + n
        off += (-(off - 4)) % 8
        if len(buf) >= off + 48:
            sec, nsec = _STAMP.unpack_from(buf, 4)
            if dof == 1:
                return sec * NS + nsec, np.array(_D.unpack_from(buf, off + 16))
            return sec * NS + nsec, np.array(_D6.unpack_from(buf, off))
    m = deserialize_message(buf, msg_type)
    a, b = (m.twist.linear, m.twist.angular) if msg_type is TwistStamped else \
        (m.wrench.force, m.wrench.torque)
    v = np.array([a.z]) if dof == 1 else np.array([a.x, a.y, a.z, b.x, b.y, b.z])
    return stamp_ns(m.header.stamp), v


def read_frame(buf: bytes, msg_type: Any) -> str:
    """``header.frame_id`` of a serialized stamped message."""
    if buf[:2] == _LE and len(buf) >= 16:
        n = _U32.unpack_from(buf, 12)[0]
        if 0 < n <= len(buf) - 16:
            return bytes(buf[16:16 + n - 1]).decode(errors="replace")
    return str(deserialize_message(buf, msg_type).header.frame_id)


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
        lay = cdr.message_layout(cdr.JOINT_STATE, "", names, counts)
        self._template = bytes(lay.buf)
        self._off = lay.fields[field][0]
        self._n = n

    def encode(self, ns: int, values: Array) -> bytes:
        """CDR bytes of the message stamped ``ns`` carrying ``values`` (n,)."""
        b = bytearray(self._template)
        _STAMP.pack_into(b, 4, ns // NS, ns % NS)
        b[self._off:self._off + 8 * self._n] = np.asarray(values, "<f8").tobytes()
        return bytes(b)


def names_blob(names: Sequence[str]) -> bytes:
    """The serialized ``name`` sequence (count + strings) as :func:`read_joint_state` returns
    it, for comparing a message's channels without decoding them."""
    return _parse_joint_state(JointStateWriter(names, "velocity").encode(0, np.zeros(
        len(names))))[1]


def read_joint_state(buf: bytes) -> tuple[int, bytes | list[str], Array]:
    """(stamp ns, names, velocity (n,)) of a serialized JointState.

    ``names`` is the raw ``name`` sequence (compare with :func:`names_blob`) on the fast path,
    a list of str when the message went through rclpy's deserialisation.
    """
    if buf[:2] == _LE:
        try:
            return _parse_joint_state(buf)
        except (struct.error, ValueError):
            pass  # truncated or odd: let rclpy judge it
    m = deserialize_message(buf, JointState)
    return stamp_ns(m.header.stamp), list(m.name), np.asarray(m.velocity, dtype=np.float64)


def _parse_joint_state(buf: bytes) -> tuple[int, bytes, Array]:
    sec, nsec = _STAMP.unpack_from(buf, 4)
    pos = 16 + _U32.unpack_from(buf, 12)[0]  # after frame_id
    pos += (-(pos - 4)) % 4
    start = pos
    count = _U32.unpack_from(buf, pos)[0]
    pos += 4
    for _ in range(count):
        pos += (-(pos - 4)) % 4
        pos += 4 + _U32.unpack_from(buf, pos)[0]
    blob = buf[start:pos]
    velocity = np.zeros(0)
    for field in range(3):  # position, velocity, effort
        pos += (-(pos - 4)) % 4
        n = _U32.unpack_from(buf, pos)[0]
        pos += 4
        if n:
            pos += (-(pos - 4)) % 8
            if pos + 8 * n > len(buf):
                raise ValueError("truncated JointState")
            if field == 1:
                velocity = np.frombuffer(buf, "<f8", n, pos).astype(np.float64)
            pos += 8 * n
    return sec * NS + nsec, blob, velocity


def header_bytes(ns: int, frame: str = "") -> bytes:
    """CDR bytes of a std_msgs/Header stamped ``ns`` (int ns) with ``frame``."""
    raw = frame.encode() + b"\x00"
    return _LE + b"\x00\x00" + _STAMP.pack(ns // NS, ns % NS) + _U32.pack(len(raw)) + raw


def read_header(buf: bytes) -> tuple[int, str]:
    """(stamp ns, frame_id) of a serialized std_msgs/Header."""
    if buf[:2] == _LE and len(buf) >= 16:
        n = _U32.unpack_from(buf, 12)[0]
        if n >= 1 and len(buf) >= 16 + n:
            sec, nsec = _STAMP.unpack_from(buf, 4)
            return sec * NS + nsec, buf[16:15 + n].decode(errors="replace")
    m = deserialize_message(buf, Header)
    return stamp_ns(m.stamp), str(m.frame_id)


def names_of(blob: bytes) -> list[str]:
    """Decode a raw ``name`` sequence (from :func:`read_joint_state`)."""
    count = _U32.unpack_from(blob, 0)[0]
    pos, out = 4, []
    for _ in range(count):
        pos += (-pos) % 4  # the blob starts 4-aligned in its message
        n = _U32.unpack_from(blob, pos)[0]
        out.append(blob[pos + 4:pos + 3 + n].decode())
        pos += 4 + n
    return out
