"""merge_bags: the parts of a per-process recording become one bag, as one recorder writes it."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.bagio import LATCHED_QOS, open_bag
from dcsms_ros.analysis.bagmerge import merge_bags
from dcsms_ros.analysis.gaps import PUBLISHED_KEY
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.errors import BagError


def _part(path: Path, topic: str, times: list[int], published: int | None = None,
          qos: str = "") -> list[bytes]:
    """A closed bag of ``topic`` (TwistStamped) with one message per time; its payloads."""
    t = np.array(times, dtype=np.int64)
    data = cdr.encode_stamped(cdr.TWIST_STAMPED, t, "stage1",
                              np.arange(6.0 * len(t)).reshape(-1, 6))
    w = McapBagWriter(path, chunk_bytes=300)  # several chunks per part
    w.add_topic(topic, cdr.TWIST_STAMPED, qos)
    for ti, d in zip(times, data, strict=True):
        w.write(topic, ti, bytes(d))
    if published is not None:
        w.set_custom_data(PUBLISHED_KEY, json.dumps({topic: published}))
    w.close()
    return [bytes(d) for d in data]


def _info(bag: Path) -> dict:
    return yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def test_messages_interleave_by_log_time_with_their_bytes_types_and_qos(tmp_path: Path) -> None:
    a_times, b_times = list(range(1, 40, 2)), list(range(2, 30, 3))
    a = _part(tmp_path / "a", "/dcsms/velocity/stage1", a_times, published=20, qos=LATCHED_QOS)
    b = _part(tmp_path / "b", "/dcsms/force/fb_stage1", b_times, published=12)
    out = tmp_path / "bag"
    counts = merge_bags([tmp_path / "a", tmp_path / "b"], out)
    assert counts == {"/dcsms/velocity/stage1": 20, "/dcsms/force/fb_stage1": 10}
    with Reader(out) as r:
        got = [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    want = sorted([("/dcsms/velocity/stage1", t, d) for t, d in zip(a_times, a, strict=True)]
                  + [("/dcsms/force/fb_stage1", t, d) for t, d in zip(b_times, b, strict=True)],
                  key=lambda m: m[1])
    assert got == want
    assert len(qos["/dcsms/velocity/stage1"]) == 1 and qos["/dcsms/force/fb_stage1"] == []
    info = _info(out)
    assert json.loads(info["custom_data"][PUBLISHED_KEY]) == {
        "/dcsms/velocity/stage1": 20, "/dcsms/force/fb_stage1": 12}
    assert info["message_count"] == 30
    profiles = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
                for t in info["topics_with_message_count"]}
    assert profiles["/dcsms/velocity/stage1"] == yaml.safe_load(LATCHED_QOS)


def test_a_topic_in_two_inputs_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    _part(tmp_path / "a", "/dcsms/sensors/raw", [1, 2])
    _part(tmp_path / "b", "/dcsms/sensors/raw", [3])
    out = tmp_path / "bag"
    with pytest.raises(BagError, match=r"/dcsms/sensors/raw: in .* and in"):
        merge_bags([tmp_path / "a", tmp_path / "b"], out)
    assert not out.exists() and not tmp_path.joinpath("bag.partial").exists()


def test_an_unfinished_input_is_refused(tmp_path: Path) -> None:
    _part(tmp_path / "a", "/dcsms/sensors/raw", [1, 2])
    (tmp_path / "b").mkdir()  # a process killed before it closed its part
    with pytest.raises(BagError, match="not a closed bag"):
        merge_bags([tmp_path / "a", tmp_path / "b"], tmp_path / "bag")
    assert not tmp_path.joinpath("bag").exists()


def _strings(path: Path, topic: str, times: list[int], storage: str = "mcap") -> list[bytes]:
    """A closed bag of ``topic`` (std_msgs/String, a different size each) written by ``storage``
    (MCAP by our writer, SQLite by rosbags); its payloads."""
    data = [cdr.encode_string("x" * (i % 7)) for i in range(len(times))]
    if storage == "mcap":
        w = McapBagWriter(path, chunk_bytes=200)
        w.add_topic(topic, "std_msgs/msg/String")
        for ti, d in zip(times, data, strict=True):
            w.write(topic, ti, d)
        w.close()
    else:
        with open_bag(path, storage) as b:
            b.add_topic(topic, "std_msgs/msg/String")
            for ti, d in zip(times, data, strict=True):
                b.write(topic, ti, d)
    return data


def _merged(out: Path) -> list[tuple[str, int, bytes]]:
    """The merged bag's messages as the file holds them (rosbags would sort them by time on
    reading), after checking that its chunks follow each other in time, as rosbags assumes."""
    with open(out / "bag.mcap", "rb") as f:
        reader = make_reader(f)
        chunks = sorted(reader.get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
        assert all(a.message_end_time <= b.message_start_time
                   for a, b in itertools.pairwise(chunks))
        got = [(ch.topic, m.log_time, m.data) for _, ch, m in
               reader.iter_messages(log_time_order=False)]
    with Reader(out) as r:
        assert [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()] == got
    return got


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_log_time_order_ties_in_input_order_sizes_and_an_empty_part(tmp_path: Path,
                                                                    storage: str) -> None:
    """Chunk-wise (every input an indexed MCAP file) and message by message (a SQLite input):
    the same bag, every message once, by log time, a tie in the order of the inputs."""
    rng = np.random.default_rng(3)
    a_t = np.sort(rng.choice(400, 150, replace=False)).tolist()
    b_t = np.sort(rng.choice(400, 120, replace=False)).tolist()  # ties with a's times
    a = _part(tmp_path / "a", "/dcsms/velocity/stage1", a_t)
    b = _strings(tmp_path / "b", "/dcsms/mode", b_t, storage)
    w = McapBagWriter(tmp_path / "c")  # a process that recorded nothing
    w.add_topic("/dcsms/force/fb_stage1", cdr.WRENCH_STAMPED)
    w.close()
    out = tmp_path / "bag"
    counts = merge_bags([tmp_path / "a", tmp_path / "b", tmp_path / "c"], out)
    assert counts == {"/dcsms/velocity/stage1": 150, "/dcsms/mode": 120,
                      "/dcsms/force/fb_stage1": 0}
    want = sorted([(t, 0, i, "/dcsms/velocity/stage1", d) for i, (t, d) in
                   enumerate(zip(a_t, a, strict=True))]
                  + [(t, 1, i, "/dcsms/mode", d) for i, (t, d) in
                     enumerate(zip(b_t, b, strict=True))])
    assert _merged(out) == [(topic, t, d) for t, _, _, topic, d in want]
    assert _info(out)["message_count"] == 270


def test_a_part_whose_chunks_overlap_in_time_merges_in_order(tmp_path: Path) -> None:
    """Chunks of one input may span overlapping times (a recorder's slow topic beside a fast
    one): a message is written only once no unread chunk can hold an earlier one."""
    fast, slow = list(range(0, 3000, 3)), list(range(1, 3000, 250))
    w = McapBagWriter(tmp_path / "a", chunk_bytes=2000)
    w.add_topic("/fast", cdr.TWIST_STAMPED)
    w.add_topic("/slow", "std_msgs/msg/String")
    payload = {"/fast": bytes(cdr.encode_stamped(cdr.TWIST_STAMPED, np.array([0]), "s",
                                                 np.zeros((1, 6)))[0]),
               "/slow": cdr.encode_string("slow")}
    msgs = sorted([(t, "/fast") for t in fast] + [(t, "/slow") for t in slow])
    for t, topic in msgs:
        w.write(topic, t, payload[topic])
    w.close()
    _part(tmp_path / "b", "/dcsms/sensors/raw", list(range(2, 3000, 7)))
    out = tmp_path / "bag"
    merge_bags([tmp_path / "a", tmp_path / "b"], out)
    got = _merged(out)
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)
    assert len(got) == len(msgs) + len(range(2, 3000, 7))
    assert [(topic, t) for topic, t, _ in got if topic != "/dcsms/sensors/raw"] == \
        [(topic, t) for t, topic in msgs]
