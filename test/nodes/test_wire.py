"""Per-message CDR of the control path against rclpy's own (de)serialisation."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped, WrenchStamped
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from dcsms_ros.analysis import cdr
from dcsms_ros.nodes import wire
from dcsms_ros.nodes.msgs import stamp_ns, twist_array, twist_msg, wrench_array, wrench_msg

FRAMES = ["", "a", "ab", "abc", "stage1", "ground", "a_longer_frame_id"]
NS = [0, 1, 999_999_999, 1_000_000_000, 1_234_567_890_123]


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("dof", [1, 6])
@pytest.mark.parametrize("kind", ["twist", "wrench"])
def test_stamped_round_trip_through_rclpy(frame, dof, kind):
    """Our bytes deserialise in rclpy to the same numbers, and rclpy's bytes read back exactly."""
    rng = np.random.default_rng(len(frame) + dof)
    typ, build, read = ((TwistStamped, twist_msg, twist_array) if kind == "twist"
                        else (WrenchStamped, wrench_msg, wrench_array))
    writer = wire.StampedWriter(typ, frame, dof)
    for ns in NS:
        v = rng.normal(size=dof) * 10.0 ** rng.integers(-9, 3)
        m = deserialize_message(writer.encode(ns, v), typ)
        assert m.header.frame_id == frame and stamp_ns(m.header.stamp) == ns
        np.testing.assert_array_equal(read(m, dof), v)
        got_ns, got = wire.read_stamped(serialize_message(build(v, ns, frame)), typ, dof)
        assert got_ns == ns
        np.testing.assert_array_equal(got, v)


def test_stamped_one_dof_writes_only_z():
    """A 1-DOF vector is the z component; every other component is exactly zero."""
    m = deserialize_message(wire.StampedWriter(WrenchStamped, "stage2", 1).encode(
        5, np.array([3.5])), WrenchStamped)
    assert (m.wrench.force.x, m.wrench.force.y, m.wrench.force.z) == (0.0, 0.0, 3.5)
    assert (m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z) == (0.0, 0.0, 0.0)


def test_non_finite_values_pass_through_unchanged():
    """NaN and Inf are carried bit for bit, for the guards downstream to judge."""
    v = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1e308])
    _, got = wire.read_stamped(wire.StampedWriter(TwistStamped, "x", 6).encode(1, v),
                               TwistStamped, 6)
    np.testing.assert_array_equal(got.view(np.int64), v.view(np.int64))


def test_big_endian_message_takes_the_rclpy_path():
    """A big-endian CDR message (legal, rare) is read through rclpy's deserialisation."""
    ts = cdr.typestore()
    cls = ts.types[cdr.TWIST_STAMPED]
    hdr = ts.types["std_msgs/msg/Header"](stamp=ts.types["builtin_interfaces/msg/Time"](
        sec=3, nanosec=7), frame_id="stage1")
    vec = ts.types["geometry_msgs/msg/Vector3"]
    tw = ts.types["geometry_msgs/msg/Twist"](linear=vec(x=1.0, y=2.0, z=3.0),
                                             angular=vec(x=4.0, y=5.0, z=6.0))
    buf = bytes(ts.serialize_cdr(cls(header=hdr, twist=tw), cdr.TWIST_STAMPED,
                                 little_endian=False))
    assert buf[:2] == b"\x00\x00"
    ns, v = wire.read_stamped(buf, TwistStamped, 6)
    assert ns == 3 * 1_000_000_000 + 7
    np.testing.assert_array_equal(v, [1, 2, 3, 4, 5, 6])


@pytest.mark.parametrize("names", [["g1"], ["ground_z", "s1_a", "s1_bb", "s2_ccc"],
                                   [f"ch{i}" for i in range(18)]])
@pytest.mark.parametrize("field", ["velocity", "effort"])
def test_joint_state_writer_round_trip(names, field):
    """JointState bytes deserialise in rclpy with the names and the values of ``field``."""
    values = np.arange(len(names), dtype=float) * 0.25 - 1.0
    m = deserialize_message(wire.JointStateWriter(names, field).encode(2_500_000_001, values),
                            JointState)
    assert list(m.name) == names and stamp_ns(m.header.stamp) == 2_500_000_001
    np.testing.assert_array_equal(getattr(m, field), values)
    other = "effort" if field == "velocity" else "velocity"
    assert len(m.position) == 0 and len(getattr(m, other)) == 0


def test_read_joint_state_fast_path_matches_names_blob():
    """Our own message is recognised by its name bytes without decoding the names."""
    names = ["ground_z", "stage1_z", "stage2_z"]
    buf = wire.JointStateWriter(names, "velocity").encode(42, np.array([1.0, 2.0, 3.0]))
    ns, blob, v = wire.read_joint_state(buf)
    assert ns == 42 and blob == wire.names_blob(names)
    assert wire.names_of(blob) == names
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])


def test_read_joint_state_from_rclpy_with_every_field_filled():
    """A foreign JointState (frame_id, position and effort too) reads the right velocity."""
    m = JointState(name=["b", "a_long_name", "c"], position=[9.0], velocity=[1.0, 2.0, 3.0],
                   effort=[7.0, 8.0])
    m.header.frame_id = "odd"
    m.header.stamp.sec, m.header.stamp.nanosec = 12, 345
    ns, names, v = wire.read_joint_state(serialize_message(m))
    assert ns == 12 * 1_000_000_000 + 345
    assert (wire.names_of(names) if isinstance(names, bytes) else names) == list(m.name)
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])


def test_read_joint_state_without_velocity_is_empty():
    """A JointState with no velocity gives an empty array (the node then counts it bad)."""
    ns, _, v = wire.read_joint_state(serialize_message(JointState(name=["a"], effort=[1.0])))
    assert ns == 0 and v.shape == (0,)
