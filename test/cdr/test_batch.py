"""Batch CDR codecs (K messages as byte matrices) against rosbags and rclpy serialisation."""

from __future__ import annotations

import numpy as np
import pytest

from dcsms_ros import cdr

rclpy_ser = pytest.importorskip("rclpy.serialization")
K = 7
NS = 1_000_000_000


def _stamps(rng: np.random.Generator) -> np.ndarray:
    return (1_700_000_000 * NS + rng.integers(0, 10 * NS, K)).astype(np.int64)


def _padding_mask(msgtype: str, frame_id: str = "", names=(), counts=(0, 0, 0)) -> np.ndarray:
    lay = cdr.message_layout(msgtype, frame_id, names, counts)
    mask = lay.const.copy()
    for off, dtype, count in lay.fields.values():
        mask[off:off + np.dtype(dtype).itemsize * count] = True
    return mask


def _same_as_rclpy(mine: bytes, theirs: bytes, mask: np.ndarray) -> None:
    assert len(mine) <= len(theirs) <= len(mine) + 8  # rmw may append trailing bytes
    a = np.frombuffer(mine, np.uint8)
    b = np.frombuffer(theirs[:len(mine)], np.uint8)
    assert np.array_equal(a[mask], b[mask])  # padding bytes are uninitialised in rmw


@pytest.mark.parametrize("msgtype", [cdr.TWIST_STAMPED, cdr.WRENCH_STAMPED])
def test_stamped_matches_rosbags_and_rclpy(msgtype: str) -> None:
    """Twist/WrenchStamped: bytes equal rosbags', numbers equal rclpy's, fast decode exact."""
    from geometry_msgs.msg import TwistStamped, WrenchStamped

    rng = np.random.default_rng(1)
    t, v = _stamps(rng), rng.standard_normal((K, 6))
    bufs = cdr.encode_stamped(msgtype, t, "stage12", v)
    ts = cdr.typestore()
    mask = _padding_mask(msgtype, "stage12")
    for i, b in enumerate(bufs):
        msg = ts.deserialize_cdr(b, msgtype)
        assert ts.serialize_cdr(msg, msgtype) == b
        r = TwistStamped() if msgtype == cdr.TWIST_STAMPED else WrenchStamped()
        r.header.stamp.sec, r.header.stamp.nanosec = int(t[i] // NS), int(t[i] % NS)
        r.header.frame_id = "stage12"
        lin, ang = (r.twist.linear, r.twist.angular) if msgtype == cdr.TWIST_STAMPED else (
            r.wrench.force, r.wrench.torque)
        lin.x, lin.y, lin.z, ang.x, ang.y, ang.z = (float(x) for x in v[i])
        _same_as_rclpy(b, bytes(rclpy_ser.serialize_message(r)), mask)
    d = cdr.decode_batch(msgtype, bufs)
    key = "twist" if msgtype == cdr.TWIST_STAMPED else "wrench"
    assert d.fast and d.frame_id == "stage12"
    assert np.array_equal(d.stamp_ns, t) and np.array_equal(d.fields[key], v)


def test_joint_state_matches_rosbags_and_rclpy() -> None:
    """JointState with names, an empty position and velocity/effort arrays round-trips."""
    from sensor_msgs.msg import JointState

    rng = np.random.default_rng(2)
    names = ["stage1/z", "stage2/zz", "g"]
    t, vel, eff = _stamps(rng), rng.standard_normal((K, 3)), rng.standard_normal((K, 3))
    bufs = cdr.encode_joint_state(t, "base", names, velocity=vel, effort=eff)
    ts = cdr.typestore()
    mask = _padding_mask(cdr.JOINT_STATE, "base", names, (0, 3, 3))
    rclpy_bufs = []
    for i, b in enumerate(bufs):
        msg = ts.deserialize_cdr(b, cdr.JOINT_STATE)
        assert list(msg.name) == names and msg.position.size == 0
        assert ts.serialize_cdr(msg, cdr.JOINT_STATE) == b
        r = JointState(name=names, velocity=vel[i].tolist(), effort=eff[i].tolist())
        r.header.stamp.sec, r.header.stamp.nanosec = int(t[i] // NS), int(t[i] % NS)
        r.header.frame_id = "base"
        rb = bytes(rclpy_ser.serialize_message(r))
        _same_as_rclpy(b, rb, mask)
        rclpy_bufs.append(rb)
    for batch in (bufs, rclpy_bufs):  # rclpy's garbage padding must not defeat the fast path
        d = cdr.decode_batch(cdr.JOINT_STATE, batch)
        assert d.fast and d.names == tuple(names)
        assert np.array_equal(d.fields["velocity"], vel)
        assert np.array_equal(d.fields["effort"], eff)
        assert d.fields["position"].shape == (K, 0)


def test_string_and_clock_match_rosbags_and_rclpy() -> None:
    """String and Clock bytes equal rosbags' and rclpy's."""
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String

    ts = cdr.typestore()
    for text in ("DFBC+FFC", "", "Passive"):
        b = cdr.encode_string(text)
        assert b == ts.serialize_cdr(ts.types[cdr.STRING](data=text), cdr.STRING)
        assert b == bytes(rclpy_ser.serialize_message(String(data=text)))
        assert cdr.decode_string(b) == text
    t = np.array([0, 1, NS + 5, 3 * NS - 1], dtype=np.int64)
    bufs = cdr.encode_clock(t)
    for i, b in enumerate(bufs):
        c = Clock()
        c.clock.sec, c.clock.nanosec = int(t[i] // NS), int(t[i] % NS)
        assert b == bytes(rclpy_ser.serialize_message(c))
        m = ts.deserialize_cdr(b, cdr.CLOCK)
        assert m.clock.sec * NS + m.clock.nanosec == t[i]
    assert np.array_equal(cdr.decode_batch(cdr.CLOCK, bufs).stamp_ns, t)


def test_layout_change_falls_back_to_rosbags() -> None:
    """A batch whose frame_id changes mid-way decodes correctly through the slow path."""
    rng = np.random.default_rng(3)
    t, v = _stamps(rng), rng.standard_normal((K, 6))
    bufs = (cdr.encode_stamped(cdr.TWIST_STAMPED, t[:3], "a", v[:3])
            + cdr.encode_stamped(cdr.TWIST_STAMPED, t[3:], "b", v[3:]))  # same size, other id
    d = cdr.decode_batch(cdr.TWIST_STAMPED, bufs)
    assert not d.fast
    assert np.array_equal(d.fields["twist"], v) and np.array_equal(d.stamp_ns, t)
