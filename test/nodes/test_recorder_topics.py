"""How the recorder takes a topic (nodes/recorder_topics.py): the QoS rule rosbag2 applies to
the offered profiles, and the metadata read back by rosbags' own parser."""

from __future__ import annotations

import pytest
from rclpy.duration import Duration, Infinite
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2.metadata import parse_qos

from dcsms_ros.cdr import CLOCK
from dcsms_ros.nodes.recorder_topics import is_stamped, msg_class, qos_yaml, subscription_qos

REL, BE = ReliabilityPolicy.RELIABLE, ReliabilityPolicy.BEST_EFFORT
TL, VOL = DurabilityPolicy.TRANSIENT_LOCAL, DurabilityPolicy.VOLATILE


def _offered(rel: ReliabilityPolicy, dur: DurabilityPolicy) -> QoSProfile:
    return QoSProfile(depth=1, reliability=rel, durability=dur)


@pytest.mark.parametrize(("offered", "reliability", "durability"), [
    ([(REL, TL)], REL, TL),                 # a latched topic: its history reaches the bag
    ([(REL, VOL), (REL, TL)], REL, VOL),    # one volatile writer: no history to ask for
    ([(BE, VOL)], BE, VOL),                 # a per-sample stream
    ([(REL, TL), (BE, TL)], BE, TL),        # one best-effort writer: reliable would miss it
])
def test_the_subscription_matches_every_offered_profile(offered, reliability,
                                                        durability) -> None:
    q = subscription_qos([_offered(r, d) for r, d in offered], depth=4000)
    assert (q.reliability, q.durability) == (reliability, durability)
    assert (q.history, q.depth) == (HistoryPolicy.KEEP_LAST, 4000)


def test_offered_profiles_read_back_by_rosbags() -> None:
    profiles = [QoSProfile(depth=7, reliability=BE, durability=VOL),
                QoSProfile(depth=1, reliability=REL, durability=TL,
                           deadline=Duration(seconds=2, nanoseconds=5),
                           lifespan=Infinite)]
    back = parse_qos(qos_yaml(profiles))
    assert [q.depth for q in back] == [7, 1]
    assert [q.reliability.name for q in back] == ["BEST_EFFORT", "RELIABLE"]
    assert [q.durability.name for q in back] == ["VOLATILE", "TRANSIENT_LOCAL"]
    assert (back[1].deadline.sec, back[1].deadline.nsec) == (2, 5)
    # rclpy's infinite duration as rosbag2 writes it: {sec: 9223372036, nsec: 854775807}
    assert back[1].lifespan.sec * 10**9 + back[1].lifespan.nsec == 2**63 - 1


@pytest.mark.parametrize(("msgtype", "stamped"), [
    ("geometry_msgs/msg/TwistStamped", True),
    ("sensor_msgs/msg/JointState", True),
    ("std_msgs/msg/String", False),
    ("std_msgs/msg/Int64", False),
    (CLOCK, True),
])
def test_which_types_open_with_a_stamp(msgtype: str, stamped: bool) -> None:
    assert is_stamped(msg_class(msgtype), msgtype) is stamped
