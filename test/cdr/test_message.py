"""Per-message CDR of the control path against rclpy's own (de)serialisation, and the layouts
that writers and readers share."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from rosmsgs import stamp_ns, twist_array, twist_msg, wrench_array, wrench_msg
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from dcsms_ros import cdr

FRAMES = ["", "a", "ab", "abc", "stage1", "ground", "a_longer_frame_id"]
NS = [0, 1, 999_999_999, 1_000_000_000, 1_234_567_890_123]


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("dof", [1, 6])
@pytest.mark.parametrize("kind", ["twist", "wrench"])
def test_stamped_round_trip_through_rclpy(frame, dof, kind):
    """Our bytes deserialise in rclpy to the same numbers, and rclpy's bytes read back exactly."""
    rng = np.random.default_rng(len(frame) + dof)
    typ, msgtype, build, read = (
        (TwistStamped, cdr.TWIST_STAMPED, twist_msg, twist_array) if kind == "twist"
        else (WrenchStamped, cdr.WRENCH_STAMPED, wrench_msg, wrench_array))
    writer = cdr.StampedWriter(msgtype, frame, dof)
    for ns in NS:
        v = rng.normal(size=dof) * 10.0 ** rng.integers(-9, 3)
        m = deserialize_message(writer.encode(ns, v), typ)
        assert m.header.frame_id == frame and stamp_ns(m.header.stamp) == ns
        np.testing.assert_array_equal(read(m, dof), v)
        theirs = serialize_message(build(v, ns, frame))
        got_ns, got = cdr.read_stamped(theirs, msgtype, dof)
        assert got_ns == ns and cdr.read_frame(theirs, msgtype) == frame
        np.testing.assert_array_equal(got, v)


def test_stamped_one_dof_writes_only_z():
    """A 1-DOF vector is the z component; every other component is exactly zero."""
    m = deserialize_message(cdr.StampedWriter(cdr.WRENCH_STAMPED, "stage2", 1).encode(
        5, np.array([3.5])), WrenchStamped)
    assert (m.wrench.force.x, m.wrench.force.y, m.wrench.force.z) == (0.0, 0.0, 3.5)
    assert (m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z) == (0.0, 0.0, 0.0)


def test_non_finite_values_pass_through_unchanged():
    """NaN and Inf are carried bit for bit, for the guards downstream to judge."""
    v = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1e308])
    _, got = cdr.read_stamped(cdr.StampedWriter(cdr.TWIST_STAMPED, "x", 6).encode(1, v),
                              cdr.TWIST_STAMPED, 6)
    np.testing.assert_array_equal(got.view(np.int64), v.view(np.int64))


def _big_endian_twist() -> bytes:
    ts = cdr.typestore()
    hdr = ts.types["std_msgs/msg/Header"](stamp=ts.types["builtin_interfaces/msg/Time"](
        sec=3, nanosec=7), frame_id="stage1")
    vec = ts.types["geometry_msgs/msg/Vector3"]
    tw = ts.types["geometry_msgs/msg/Twist"](linear=vec(x=1.0, y=2.0, z=3.0),
                                             angular=vec(x=4.0, y=5.0, z=6.0))
    msg = ts.types[cdr.TWIST_STAMPED](header=hdr, twist=tw)
    return bytes(ts.serialize_cdr(msg, cdr.TWIST_STAMPED, little_endian=False))


def test_big_endian_message_takes_the_rosbags_path():
    """A big-endian CDR message (legal, rare) is read through rosbags' deserialisation."""
    buf = _big_endian_twist()
    assert buf[:2] == b"\x00\x00"
    ns, v = cdr.read_stamped(buf, cdr.TWIST_STAMPED, 6)
    assert ns == 3 * 1_000_000_000 + 7 == cdr.read_stamp(buf)
    np.testing.assert_array_equal(v, [1, 2, 3, 4, 5, 6])
    assert cdr.read_frame(buf, cdr.TWIST_STAMPED) == "stage1"


def test_malformed_message_is_a_value_error():
    """A message neither path can read raises ValueError (not rosbags' own exceptions)."""
    buf = cdr.StampedWriter(cdr.TWIST_STAMPED, "stage1", 6).encode(1, np.zeros(6))
    with pytest.raises(ValueError, match="TwistStamped"):
        cdr.read_stamped(buf[:30], cdr.TWIST_STAMPED, 6)


@pytest.mark.parametrize("names", [["g1"], ["ground_z", "s1_a", "s1_bb", "s2_ccc"],
                                   [f"ch{i}" for i in range(18)]])
@pytest.mark.parametrize("field", ["velocity", "effort"])
def test_joint_state_writer_round_trip(names, field):
    """JointState bytes deserialise in rclpy with the names and the values of ``field``."""
    values = np.arange(len(names), dtype=float) * 0.25 - 1.0
    m = deserialize_message(cdr.JointStateWriter(names, field).encode(2_500_000_001, values),
                            JointState)
    assert list(m.name) == names and stamp_ns(m.header.stamp) == 2_500_000_001
    np.testing.assert_array_equal(getattr(m, field), values)
    other = "effort" if field == "velocity" else "velocity"
    assert len(m.position) == 0 and len(getattr(m, other)) == 0


def test_joint_state_reader_keeps_one_names_tuple_per_layout():
    """Messages of one layout give the same names object; another layout is learnt, and the
    first one again after it."""
    names = ["ground_z", "stage1_z", "stage2_z"]
    writer = cdr.JointStateWriter(names, "velocity")
    reader = cdr.JointStateReader("velocity")
    ns, first, v = reader.read(writer.encode(42, np.array([1.0, 2.0, 3.0])))
    assert ns == 42 and first == tuple(names)
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])
    assert reader.read(writer.encode(43, np.zeros(3)))[1] is first
    other = cdr.JointStateWriter(names[::-1], "velocity").encode(44, np.array([3.0, 2.0, 1.0]))
    ns, rev, v = reader.read(other)
    assert ns == 44 and rev == tuple(names[::-1])
    np.testing.assert_array_equal(v, [3.0, 2.0, 1.0])
    ns, again, _ = reader.read(writer.encode(45, np.zeros(3)))
    assert ns == 45 and again == first


def test_read_joint_state_from_rclpy_with_every_field_filled():
    """A foreign JointState (frame_id, position and effort too) reads the right fields."""
    m = JointState(name=["b", "a_long_name", "c"], position=[9.0], velocity=[1.0, 2.0, 3.0],
                   effort=[7.0, 8.0])
    m.header.frame_id = "odd"
    m.header.stamp.sec, m.header.stamp.nanosec = 12, 345
    buf = serialize_message(m)
    ns, names, v = cdr.JointStateReader("velocity").read(buf)
    assert ns == 12 * 1_000_000_000 + 345 and names == tuple(m.name)
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(cdr.JointStateReader("effort").read(buf)[2], [7.0, 8.0])


def test_read_joint_state_without_velocity_is_empty():
    """A JointState with no velocity gives an empty array (the node then counts it bad)."""
    buf = serialize_message(JointState(name=["a"], effort=[1.0]))
    ns, _, v = cdr.JointStateReader("velocity").read(buf)
    assert ns == 0 and v.shape == (0,)


def test_uninitialised_padding_still_matches_the_layout():
    """rmw leaves padding bytes uninitialised: a message whose padding is not zero still has
    its layout; a changed constant byte (a name) does not."""
    names = ["a", "bb"]
    lay = cdr.message_layout(cdr.JOINT_STATE, "", names, (0, 2, 0))
    buf = np.frombuffer(bytearray(cdr.JointStateWriter(names, "velocity").encode(
        1, np.ones(2))), np.uint8)
    padding = ~lay.const
    for off, dtype, count in lay.fields.values():
        padding[off:off + np.dtype(dtype).itemsize * count] = False
    padding[2:4] = False  # encapsulation options
    assert padding.any()
    buf[padding] = 0xAB
    assert lay.matches(buf.tobytes())
    ns, got, v = cdr.JointStateReader().read(buf.tobytes())
    assert ns == 1 and got == tuple(names)
    np.testing.assert_array_equal(v, [1.0, 1.0])
    buf[lay.segments[2][0] + 8] ^= 1  # the first name's letter (after count and length)
    assert not lay.matches(buf.tobytes())


@pytest.mark.parametrize("frame", ["", "check", "tripped"])
def test_header_matches_rclpy(frame):
    """std_msgs/Header bytes equal rclpy's; rclpy's read back."""
    h = Header(frame_id=frame)
    h.stamp.sec, h.stamp.nanosec = 7, 123
    theirs = bytes(serialize_message(h))
    mine = cdr.header_bytes(7_000_000_123, frame)
    assert theirs[:len(mine)] == mine
    assert cdr.read_header(theirs) == (7_000_000_123, frame) == cdr.read_header(mine)


@pytest.mark.parametrize("ns", [0, 7_000_000_123, 86_400 * 10**9 + 999_999_999])
def test_clock_matches_rclpy(ns):
    """rosgraph_msgs/Clock bytes equal rclpy's (no padding in a Clock) and read back."""
    clock = Clock()
    clock.clock.sec, clock.clock.nanosec = ns // 10**9, ns % 10**9
    assert cdr.clock_bytes(ns) == bytes(serialize_message(clock))
    assert cdr.read_stamp(cdr.clock_bytes(ns)) == ns
    assert cdr.clock_bytes(ns) == cdr.encode_clock(np.array([ns]))[0]


def test_read_stamp_of_every_stamped_type():
    """The stamp sits at the same offset in Clock and in every header type."""
    clock = Clock()
    clock.clock.sec, clock.clock.nanosec = 5, 6
    assert cdr.read_stamp(bytes(serialize_message(clock))) == 5_000_000_006
    assert cdr.read_stamp(serialize_message(twist_msg(np.zeros(1), 99, "x"))) == 99
    assert cdr.read_stamp(cdr.header_bytes(-1)) == -1
    assert cdr.read_stamp(b"\x00\x01\x00\x00") is None
    assert cdr.read_stamp(b"\x00\x02" + bytes(20)) is None  # not plain CDR


@pytest.mark.parametrize("msgtype,args", [
    (cdr.TWIST_STAMPED, ("stage1",)), (cdr.WRENCH_STAMPED, ("",)),
    (cdr.JOINT_STATE, ("base", ["a", "bb", "ccc"], (1, 3, 0))),
    (cdr.HEADER, ("abcd",)), (cdr.CLOCK, ())])
def test_one_definition_builds_and_reads(msgtype, args):
    """The layout read from a message's bytes is the one its writer built."""
    built = cdr.message_layout(msgtype, *args)
    got = cdr.read_layout(msgtype, built.buf + b"\x00\x00\x00")  # rmw may append bytes
    assert got.buf == built.buf and got.fields == built.fields
    assert np.array_equal(got.const, built.const) and got.strings == built.strings
    with pytest.raises(ValueError, match=r"truncated|bad string"):
        cdr.read_layout(msgtype, built.buf[:-1] if built.size > 12 else built.buf[:10])


def test_string_has_no_fixed_layout():
    """String's text is the whole message: the layout API refuses it, the codec handles it."""
    with pytest.raises(ValueError, match="no fixed layout"):
        cdr.message_layout(cdr.STRING)
    assert cdr.decode_string(cdr.encode_string("FBC")) == "FBC"


@pytest.mark.parametrize("dof", [1, 6])
@pytest.mark.parametrize("frame", ["stage1", "a_longer_frame_id"])
def test_the_floats_reader_and_writer_are_the_arrays_to_the_bit(dof: int, frame: str) -> None:
    """read_stamped_floats gives read_stamped's values as a tuple of Python floats, and a
    writer packs Python floats into the same bytes as the array (NaN and signed zero too)."""
    for msgtype in (cdr.TWIST_STAMPED, cdr.WRENCH_STAMPED):
        w = cdr.StampedWriter(msgtype, frame, dof)
        v = np.array([-0.0, 1e-300, np.nan, -np.inf, 3.25, 7e12])[:dof]
        buf = w.encode(1_234_567_890_123, v)
        assert w.encode(1_234_567_890_123, v.tolist()) == buf
        assert w.encode(1_234_567_890_123, tuple(v.tolist())) == buf
        ns, got = cdr.read_stamped_floats(buf, msgtype, dof)
        ns_a, want = cdr.read_stamped(buf, msgtype, dof)
        assert ns == ns_a == 1_234_567_890_123
        assert type(got) is tuple and all(type(f) is float for f in got)
        assert np.array(got).tobytes() == want.tobytes()


def _rclpy_diagnostics(ns, statuses):
    arr = DiagnosticArray()
    arr.header.stamp.sec, arr.header.stamp.nanosec = ns // 10**9, ns % 10**9
    arr.status = [DiagnosticStatus(level=bytes([lv]), name=name, message=msg, hardware_id=hw,
                                   values=[KeyValue(key=k, value=str(v)) for k, v in kv.items()])
                  for lv, name, msg, hw, kv in statuses]
    return arr


@pytest.mark.parametrize("statuses", [
    [],
    [(0, "dcsms/plant_simulator", "", "dcsms", {})],
    [(1, "a", "bc", "", {"k": 1}), (3, "dcsms/fb_stage1/x", "tripped: loud floor", "dcsms",
                                    {"late": 12, "p99_s": 1.25e-4, "mode": "DFBC+FFC", "": ""})],
    [(2, "n" * 7, "m" * 5, "h" * 3, {f"key_{j}": 1.2345 * j for j in range(15)})] * 3,
])
@pytest.mark.parametrize("ns", [0, 7_000_000_123])
def test_diagnostics_read_back_by_rclpy_as_rclpy_builds_them(ns, statuses):
    """A /diagnostics array serialised in Python is the message rclpy builds from the same
    values, of the same size (strings of every length mod 4: the alignment)."""
    mine = cdr.encode_diagnostics(ns, statuses)
    theirs = _rclpy_diagnostics(ns, statuses)
    assert deserialize_message(mine, DiagnosticArray) == theirs
    assert len(mine) == len(serialize_message(theirs))
