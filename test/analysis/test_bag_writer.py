"""BagWriter: bags readable by rosbags and the independent mcap readers; safe failure modes."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.bagio import LATCHED_QOS, open_bag
from dcsms_ros.errors import BagError

K = 300


def _write(path: Path, storage: str = "mcap") -> dict[str, int]:
    t = 5_000_000_000 + np.arange(K, dtype=np.int64) * 500_000
    with open_bag(path, storage) as w:
        w.add_topic("/dcsms/mode", "std_msgs/String", LATCHED_QOS)
        w.add_topic("/dcsms/velocity/stage1", cdr.TWIST_STAMPED)
        w.add_topic("/dcsms/actuators/applied", cdr.JOINT_STATE)
        w.add_topic("/clock", cdr.CLOCK)
        w.write("/dcsms/mode", int(t[0]), cdr.encode_string("FBC"))
        w.write_many("/dcsms/velocity/stage1", t,
                     cdr.encode_stamped(cdr.TWIST_STAMPED, t, "stage1", np.ones((K, 6))))
        w.write_many("/dcsms/actuators/applied", t[::2],
                     cdr.encode_joint_state(t[::2], "", ["a", "b"], effort=np.ones((K // 2, 2))))
        w.write_many("/clock", t, cdr.encode_clock(t))
        return dict(w.counts)  # before the bag is closed


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_rosbags_reads_back_counts(tmp_path: Path, storage: str) -> None:
    """rosbags reads every message of a written bag, per topic, from both storages."""
    counts = _write(tmp_path / "bag", storage)
    assert counts == {"/dcsms/mode": 1, "/dcsms/velocity/stage1": K,
                      "/dcsms/actuators/applied": K // 2, "/clock": K}
    with Reader(tmp_path / "bag") as r:
        got = Counter(c.topic for c, _, _ in r.messages())
        meta = {c.topic: c.msgcount for c in r.connections}
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    assert dict(got) == counts == meta
    assert qos["/dcsms/mode"][0].depth == 1
    assert not (tmp_path / "bag.partial").exists()


def test_mcap_library_reads_same_counts(tmp_path: Path) -> None:
    """The independent mcap + mcap_ros2 readers decode every message with the same counts."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts = _write(tmp_path / "bag")
    files = list((tmp_path / "bag").glob("*.mcap"))
    assert [f.name for f in files] == ["bag.mcap"]
    got: Counter[str] = Counter()
    with files[0].open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            got[channel.topic] += 1
            if channel.topic == "/dcsms/mode":
                assert msg.data == "FBC"
            elif channel.topic == "/dcsms/velocity/stage1":
                assert msg.header.frame_id == "stage1" and msg.twist.angular.z == 1.0
    assert dict(got) == counts


def test_existing_output_is_an_error(tmp_path: Path) -> None:
    """An existing output path raises BagError naming it and is left untouched."""
    out = tmp_path / "bag"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    with pytest.raises(BagError, match=str(out)):
        open_bag(out).__enter__()
    assert (out / "keep.txt").read_text() == "x"


def test_exception_leaves_no_bag(tmp_path: Path) -> None:
    """An exception while writing leaves neither the bag nor its staging directory."""
    out = tmp_path / "bag"
    with pytest.raises(RuntimeError), open_bag(out) as w:
        w.add_topic("/clock", cdr.CLOCK)
        w.write("/clock", 1, cdr.encode_clock(np.array([1]))[0])
        raise RuntimeError("boom")
    assert not out.exists() and not (tmp_path / "bag.partial").exists()


def test_unknown_topic_and_type_are_bag_errors(tmp_path: Path) -> None:
    """Writing to an unregistered topic or adding an unknown type raises BagError."""
    with pytest.raises(BagError, match="not added"), open_bag(tmp_path / "a") as w:
        w.write("/nope", 1, b"")
    with pytest.raises(BagError, match="no_pkg"), open_bag(tmp_path / "b") as w:
        w.add_topic("/x", "no_pkg/msg/Nothing")
