"""Host lanes' rules without ROS or pipes: frames, writers of a reader, copies, DDS or not."""

from __future__ import annotations

import pytest

from dcsms_ros.protocols.lanes import (
    HEADER,
    MAX_FRAME,
    MAX_PAYLOAD,
    CopyLedger,
    FrameBuffer,
    LaneSource,
    LaneTable,
    bye,
    frame,
    hello,
    readers_without_lane,
)


def test_a_frame_holds_its_payload_and_time_and_fits_a_pipe_write() -> None:
    data = bytes(range(200))
    fr = frame(data, 1_234_567_890_123)
    assert len(fr) == HEADER.size + len(data)
    assert FrameBuffer().feed(fr) == [(data, 1_234_567_890_123)]
    assert HEADER.size + MAX_PAYLOAD == MAX_FRAME == 4096


@pytest.mark.parametrize("cut", [1, 5, 11, 12, 13, 150, 211])
def test_frames_cut_anywhere_by_a_read_come_out_whole_and_in_order(cut: int) -> None:
    """A reader's buffer may end inside a frame: the rest completes it at the next read."""
    msgs = [(bytes([i]) * (i * 7 % 50), 1000 + i) for i in range(20)]
    stream = b"".join(frame(d, t) for d, t in msgs)
    buf = FrameBuffer()
    out = []
    for i in range(0, len(stream), cut):
        out += buf.feed(stream[i:i + cut])
    assert out == msgs


def test_control_frames_name_the_writers_and_carry_no_message() -> None:
    buf = FrameBuffer()
    out = buf.feed(hello(41) + frame(b"a", 1) + hello(42) + bye(41) + frame(b"", 2))
    assert out == [(b"a", 1), (b"", 2)]
    assert buf.hellos == [41, 42] and buf.byes == [41]


def test_a_reader_is_covered_only_while_every_dds_writer_said_hello_and_lives() -> None:
    alive = {7, 8}
    src = LaneSource(lambda pid: pid in alive)
    assert not src.covered(0) and src.foreign(1) == 1  # no lane writer yet
    src.update([7], [])
    assert src.covered(1) and src.foreign(1) == 0
    assert not src.covered(2) and src.foreign(2) == 1  # another writer without a lane
    assert src.covered(0)  # a lane writer whose DDS writer has not matched yet
    src.update([8, 8], [])
    assert src.writers == [7, 8] and src.covered(2)
    src.update([], [7])  # bye
    assert src.writers == [8]
    alive.discard(8)  # killed: no bye
    src.prune()
    assert src.writers == [] and not src.covered(1)


def test_the_version_counts_only_changes_of_the_writers() -> None:
    """What a reader judged from its writers (its state) may be kept while the version holds."""
    alive = {7, 8}
    src = LaneSource(lambda pid: pid in alive)
    v = src.version
    src.update([7], [])
    assert src.version == v + 1
    src.update([7], [9])  # a repeated hello, a bye of no writer: no change
    src.prune()  # everyone alive
    assert src.version == v + 1
    src.update([8], [7])
    assert src.version == v + 3
    alive.clear()
    src.prune()
    assert src.version == v + 4 and src.writers == []


def test_each_delivered_message_cancels_one_copy_whenever_it_comes() -> None:
    ledger = CopyLedger(size=3)
    ledger.add(b"k=1")
    assert not ledger.cancel(b"k=2")
    assert ledger.cancel(b"k=1")  # its copy, however late
    assert not ledger.cancel(b"k=1")  # a lockstep retransmission of the same bytes: delivered
    ledger.add(b"k=3")
    ledger.add(b"k=3")  # sent twice: two copies to cancel
    assert ledger.cancel(b"k=3") and ledger.cancel(b"k=3") and not ledger.cancel(b"k=3")
    for k in range(5):  # copies that never came are forgotten, oldest first
        ledger.add(b"%d" % k)
    assert len(ledger) == 3 and not ledger.cancel(b"0") and ledger.cancel(b"4")


@pytest.mark.parametrize(("matched", "lanes", "size", "dds"), [
    (1, 1, 100, False),  # every reader has a lane
    (0, 0, 100, False),  # nobody reads
    (2, 1, 100, True),  # a recorder process, ros2 topic echo, another host
    (1, 2, 100, False),  # a lane reader whose DDS reader has not matched yet
    (1, 1, MAX_PAYLOAD, False),
    (1, 1, MAX_PAYLOAD + 1, True),  # too long for one atomic pipe write
])
def test_dds_carries_a_message_only_for_readers_without_a_lane(matched: int, lanes: int,
                                                                size: int, dds: bool) -> None:
    assert LaneTable.dds(matched, lanes, size) is dds


def test_a_full_lane_loses_the_message_and_it_is_counted_per_lane() -> None:
    t = LaneTable()
    t.drop("12.1")
    t.drop("12.1")
    t.drop("13.1")
    assert t.dropped == {"12.1": 2, "13.1": 1} and t.drops == 3


@pytest.mark.parametrize(("readers", "owners", "outside"), [
    (["/a", "/b"], ["/a", "/b"], 0),
    (["/a", "/b", "/rec"], ["/a", "/b"], 1),  # a recorder process
    (["/a", "/a"], ["/a"], 1),  # a node's second subscription without a lane
    (["/a"], ["/a", "/c"], 0),  # a lane reader the graph does not show yet
    (["/_NODE_NAME_UNKNOWN_"], ["/a"], 1),  # announced before its node: counted outside
])
def test_readers_without_a_lane_are_counted_by_node(readers: list[str], owners: list[str],
                                                     outside: int) -> None:
    assert readers_without_lane(readers, owners) == outside
