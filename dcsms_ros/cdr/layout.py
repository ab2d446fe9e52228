"""The byte layout of each message type, defined once, for writing and for reading.

A topic of the graph keeps one layout for its whole life: the same ``frame_id``, the same joint
names and the same number of channels. Every message of that topic then has the same size and
the same bytes everywhere except the numbers (the stamp and the float64 fields), so a
:class:`Layout` (a byte template, which bytes are constant, where each number goes) serves
every message of the topic: the encoders fill templates, the decoders check the constant bytes
and read the numbers at their offsets, message by message or as (K, R) byte matrices.

Format (OMG CDR, as rmw/Fast-CDR and rosbags write it): a 4-byte encapsulation header
``00 01 00 00`` (CDR little endian), then the body; alignment is relative to the body start, a
primitive of size n is aligned to n; a string is ``uint32 length (with NUL)``, bytes, NUL; a
sequence is ``uint32 count`` then its elements (no padding for an empty float64 sequence).
Padding bytes are written as zeros here; rmw leaves them uninitialised and may append a few
trailing bytes, so a layout never counts padding as constant and readers accept trailing bytes.

Each type's layout is one function over a :class:`_Cursor` (:data:`_DEFINITIONS`): the same
function builds the template from given strings and counts (:func:`message_layout`) and reads
them from a message's bytes (:func:`read_layout`), so writers and readers cannot disagree.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

TWIST_STAMPED = "geometry_msgs/msg/TwistStamped"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
JOINT_STATE = "sensor_msgs/msg/JointState"
HEADER = "std_msgs/msg/Header"
STRING = "std_msgs/msg/String"
CLOCK = "rosgraph_msgs/msg/Clock"

#: Message types with a layout (rosbags spelling, ``pkg/msg/Name``).
SUPPORTED = (TWIST_STAMPED, WRENCH_STAMPED, JOINT_STATE, HEADER, STRING, CLOCK)
#: JointState's float64 sequences, in message order.
JOINT_FIELDS = ("position", "velocity", "effort")
#: Name of the (6,) float64 field of a stamped vector type: ``[x y z rx ry rz]``.
VECTOR_FIELD = {TWIST_STAMPED: "twist", WRENCH_STAMPED: "wrench"}
#: ns per s; ROS Time is ``sec`` (int32) and ``nanosec`` (uint32, in [0, NS)).
NS = 1_000_000_000
#: Encapsulation identifier (first 2 bytes) of little-endian CDR (big-endian: ``00 00``).
CDR_LE = b"\x00\x01"
_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_F8 = struct.Struct("<d")
_F8X6 = struct.Struct("<6d")
#: The per-message codecs' packers, bound once: they are called as plain functions (3.11 calls
#: ``name.method()`` through a new bound method per call when ``name`` was imported).
pack_stamp, unpack_stamp = _STAMP.pack_into, _STAMP.unpack_from  # sec (int32), nanosec
unpack_stamp_be = struct.Struct(">iI").unpack_from
unpack_u32 = _U32.unpack_from
pack_f8, unpack_f8 = _F8.pack_into, _F8.unpack_from
pack_f8x6, unpack_f8x6 = _F8X6.pack_into, _F8X6.unpack_from


class Layout:
    """Byte template of one message type with fixed strings and sequence lengths.

    Built by :func:`message_layout` or :func:`read_layout` (``varies``: per byte, True for the
    numbers and the encapsulation options).

    Attributes
    ----------
    msgtype : str
        ``pkg/msg/Name``.
    buf : bytes
        The template: encapsulation header, constant bytes, zeros for numbers and padding.
    size : int
        ``len(buf)``, bytes.
    template : ndarray of uint8, shape (size,)
        ``buf`` as a read-only array (rows of byte matrices are filled from it).
    const : ndarray of bool, shape (size,)
        True where every message of the layout has the template's byte (neither a number,
        nor padding, nor the encapsulation options).
    const_idx : ndarray of intp
        ``flatnonzero(const)``.
    const_bytes : ndarray of uint8
        ``template[const_idx]``: what a message has there.
    record : numpy.dtype
        A structured dtype of ``size`` bytes with every numeric field at its offset: a (K,
        size) byte matrix viewed as K records.
    segments : tuple of (int, bytes)
        The constant bytes as runs ``(offset, bytes)`` (a message matches the layout when each
        run is found at its offset).
    blocks : tuple of (int, bytes)
        The runs between the numbers (constant bytes and zero padding): fewer than
        ``segments``, and enough for a message with zero padding.
    fields : dict of str to (int, str, int)
        Numeric field -> (byte offset, numpy dtype, count); ``sec`` and ``nanosec`` are the
        stamp.
    strings : tuple of str
        The strings in message order (``frame_id``, then JointState's names).
    frame_id : str
        ``header.frame_id`` ("" for types without a header).
    names : tuple of str
        JointState ``name`` (empty for other types).
    counts : tuple of int
        The sequence lengths in message order (JointState: names, position, velocity, effort).
    """

    def __init__(self, msgtype: str, buf: bytes | bytearray, const: Sequence[bool],
                 varies: Sequence[bool], fields: dict[str, tuple[int, str, int]],
                 strings: Sequence[str], counts: Sequence[int]) -> None:
        self.msgtype = msgtype
        self.buf = bytes(buf)
        self.size = len(self.buf)
        self.template = np.frombuffer(self.buf, np.uint8)
        self.const = np.array(const, dtype=bool)
        self.const_idx = np.flatnonzero(self.const)
        self.const_bytes = self.template[self.const_idx]
        # layouts are cached and shared: their arrays must not change
        self.const.flags.writeable = self.const_idx.flags.writeable = False
        self.const_bytes.flags.writeable = False
        self.fields = fields
        self.record = np.dtype({
            "names": list(fields), "offsets": [off for off, _, _ in fields.values()],
            "formats": [(dtype, (count,)) for _, dtype, count in fields.values()],
            "itemsize": self.size})
        self.strings = tuple(strings)
        self.counts = tuple(counts)
        # one tuple per layout: a reader hands out the same object for every message
        self.frame_id = self.strings[0] if self.strings and msgtype != STRING else ""
        self.names = self.strings[1:] if msgtype == JOINT_STATE else ()
        self.segments = self._runs(self.const)
        self.blocks = self._runs(~np.array(varies, dtype=bool))

    def _runs(self, mask: np.ndarray) -> tuple[tuple[int, bytes], ...]:
        edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.view(np.int8), [0]))))
        return tuple((a, self.buf[a:b]) for a, b in zip(
            edges[::2].tolist(), edges[1::2].tolist(), strict=True))

    def matches(self, buf: bytes) -> bool:
        """True if ``buf`` has this layout's constant bytes (trailing bytes allowed)."""
        if len(buf) < self.size:
            return False
        # zero padding (our writers, rosbags): a few runs between the numbers; rmw's padding
        # is uninitialised: then every constant run on its own
        for at, s in self.blocks:
            if not buf.startswith(s, at):
                break
        else:
            return True
        return all(buf.startswith(s, at) for at, s in self.segments)


class _Cursor:
    """Walks one message in order, appending the template as it goes.

    Building (``src`` None): strings and sequence lengths come from ``strings`` and ``counts``.
    Reading (``src`` the message): they come from the bytes, at the position the template has
    reached (the template mirrors the message byte for byte).
    """

    def __init__(self, src: bytes | None = None, strings: Iterable[str] = (),
                 counts: Iterable[int] = ()) -> None:
        if src is not None and src[:2] != CDR_LE:
            raise ValueError("not little-endian CDR")
        self.src = src
        self._strings = iter(strings)
        self._counts = iter(counts)
        self.buf = bytearray(CDR_LE + b"\x00\x00")
        self.const = [True, True, False, False]  # the options bytes are not checked
        self.varies = [False, False, True, True]  # numbers and options
        self.fields: dict[str, tuple[int, str, int]] = {}
        self.strings: list[str] = []
        self.counts: list[int] = []

    def _align(self, n: int) -> None:
        pad = (-(len(self.buf) - 4)) % n
        self.buf += b"\x00" * pad
        self.const += [False] * pad
        self.varies += [False] * pad

    def _put(self, data: bytes) -> None:
        self.buf += data
        self.const += [True] * len(data)
        self.varies += [False] * len(data)

    def _u32(self) -> int:
        """The uint32 at the (aligned) position in ``src``."""
        assert self.src is not None
        at = len(self.buf)
        if at + 4 > len(self.src):
            raise ValueError("truncated message")
        return int(unpack_u32(self.src, at)[0])

    def count(self) -> int:
        """A sequence length (uint32)."""
        self._align(4)
        n = next(self._counts) if self.src is None else self._u32()
        self._put(_U32.pack(n))
        self.counts.append(n)
        return n

    def string(self) -> None:
        """A string: length with the NUL, the UTF-8 bytes, NUL."""
        self._align(4)
        if self.src is None:
            raw = next(self._strings).encode() + b"\x00"
        else:
            n, at = self._u32(), len(self.buf) + 4
            if n < 1 or at + n > len(self.src) or self.src[at + n - 1] != 0:
                raise ValueError("bad string length")
            raw = self.src[at:at + n]
        self._put(_U32.pack(len(raw)) + raw)
        self.strings.append(raw[:-1].decode())

    def numbers(self, name: str, dtype: str, count: int = 1) -> None:
        """``count`` numbers of ``dtype`` (``<f8``, ``<i4``, ``<u4``) that vary per message."""
        size = np.dtype(dtype).itemsize
        if count:
            self._align(size)
        if self.src is not None and len(self.buf) + size * count > len(self.src):
            raise ValueError("truncated message")
        self.fields[name] = (len(self.buf), dtype, count)
        self.buf += b"\x00" * (size * count)
        self.const += [False] * (size * count)
        self.varies += [True] * (size * count)

    def stamp(self) -> None:
        """builtin_interfaces/Time (the header's stamp or Clock's time)."""
        self.numbers("sec", "<i4")
        self.numbers("nanosec", "<u4")


def _stamped_vector(key: str) -> Callable[[_Cursor], None]:
    def define(c: _Cursor) -> None:
        c.stamp()
        c.string()  # frame_id
        c.numbers(key, "<f8", 6)  # linear/force x y z, angular/torque x y z

    return define


def _joint_state(c: _Cursor) -> None:
    c.stamp()
    c.string()  # frame_id
    for _ in range(c.count()):
        c.string()  # name[i]
    for name in JOINT_FIELDS:
        c.numbers(name, "<f8", c.count())


def _header(c: _Cursor) -> None:
    c.stamp()
    c.string()


#: The one definition of each layout.
_DEFINITIONS: dict[str, Callable[[_Cursor], None]] = {
    TWIST_STAMPED: _stamped_vector("twist"),
    WRENCH_STAMPED: _stamped_vector("wrench"),
    JOINT_STATE: _joint_state,
    HEADER: _header,
    STRING: _Cursor.string,
    CLOCK: _Cursor.stamp,
}


def _walk(msgtype: str, c: _Cursor) -> Layout:
    try:
        define = _DEFINITIONS[msgtype]
    except KeyError:
        raise ValueError(f"no fixed-layout codec for {msgtype}") from None
    define(c)
    return Layout(msgtype, c.buf, c.const, c.varies, c.fields, c.strings, c.counts)


def build_layout(msgtype: str, strings: Sequence[str] = (), counts: Sequence[int] = ()
                 ) -> Layout:
    """The layout of ``msgtype`` with the given strings and sequence lengths, in message order
    (uncached; :func:`message_layout` is the cached form for the usual arguments)."""
    return _walk(msgtype, _Cursor(None, strings, counts))


@functools.lru_cache(maxsize=256)
def _cached(msgtype: str, strings: tuple[str, ...], counts: tuple[int, ...]) -> Layout:
    return build_layout(msgtype, strings, counts)


def message_layout(msgtype: str, frame_id: str = "", names: Sequence[str] = (),
                   counts: Sequence[int] = (0, 0, 0)) -> Layout:
    """The layout of one message type (cached: call it freely).

    Parameters
    ----------
    msgtype : str
        One of :data:`SUPPORTED` but :data:`STRING` (whose text is the whole message).
    frame_id : str
        ``header.frame_id`` (ignored for Clock).
    names : sequence of str, length n
        JointState ``name``.
    counts : (int, int, int)
        JointState ``position``, ``velocity``, ``effort`` lengths (0: an empty sequence).
    """
    if msgtype == STRING:
        raise ValueError("std_msgs/String has no fixed layout; use encode_string/decode_string")
    if msgtype == CLOCK:
        return _cached(msgtype, (), ())
    if msgtype == JOINT_STATE:
        return _cached(msgtype, (frame_id, *names), (len(names), *counts))
    return _cached(msgtype, (frame_id,), ())


def read_layout(msgtype: str, buf: bytes) -> Layout:
    """The layout of the message ``buf`` (little-endian CDR of ``msgtype``), read from its own
    strings and sequence lengths; trailing bytes are allowed.

    Raises
    ------
    ValueError
        Not little-endian CDR, truncated, or a string that is not NUL-terminated UTF-8.
    """
    try:
        return _walk(msgtype, _Cursor(bytes(buf)))
    except UnicodeDecodeError as exc:
        raise ValueError(f"bad string: {exc}") from None


#: Byte offsets every type with a header shares (derived from the Header layout): the stamp
#: and the uint32 length of ``header.frame_id`` right after it.
STAMP_AT = message_layout(HEADER).fields["sec"][0]
FRAME_AT = message_layout(HEADER).fields["nanosec"][0] + 4


def split_ns(stamp_ns: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """ROS Time ``sec`` (int32) and ``nanosec`` (uint32, in [0, 1e9)) of times in ns, (K,)."""
    t = np.asarray(stamp_ns, dtype=np.int64)
    return (t // NS).astype("<i4"), (t % NS).astype("<u4")


__all__ = [
    "CDR_LE", "CLOCK", "FRAME_AT", "HEADER", "JOINT_FIELDS", "JOINT_STATE", "NS",
    "STAMP_AT", "STRING", "SUPPORTED", "TWIST_STAMPED", "VECTOR_FIELD", "WRENCH_STAMPED", "Layout",
    "build_layout", "message_layout", "pack_f8", "pack_f8x6", "pack_stamp", "read_layout",
    "split_ns", "unpack_f8", "unpack_f8x6", "unpack_stamp", "unpack_stamp_be", "unpack_u32",
]
