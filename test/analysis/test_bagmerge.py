"""merge_bags: the parts of a per-process recording become one bag, as one recorder writes it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.bagio import LATCHED_QOS
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
