"""dcsms up's merge of a per-process recording's parts: the bag from every finished part; a
part left unfinished (its process killed) is named, kept with the others, and fails the run."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from dcsms_ros import cdr
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.cli.deploy import RECORDER_PART, merge_parts, parts_dir


def _part(path: Path, topic: str, n: int) -> None:
    w = McapBagWriter(path)
    w.add_topic(topic, cdr.HEADER)
    for k in range(n):
        w.write(topic, k, bytes(16))
    w.close()


def _counts(bag: Path) -> dict[str, int]:
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {t["topic_metadata"]["name"]: t["message_count"]
            for t in info["topics_with_message_count"]}


def test_finished_parts_become_the_bag_and_go(tmp_path: Path) -> None:
    bag = tmp_path / "run"
    parts = parts_dir(bag)
    _part(parts / "plant_simulator", "/dcsms/sensors/raw", 3)
    _part(parts / RECORDER_PART, "/dcsms/mode", 1)
    assert merge_parts(parts, bag) == 0
    assert _counts(bag) == {"/dcsms/sensors/raw": 3, "/dcsms/mode": 1}
    assert not parts.exists()


def test_an_unfinished_part_is_named_and_every_part_kept(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    bag = tmp_path / "run"
    parts = parts_dir(bag)
    _part(parts / "plant_simulator", "/dcsms/sensors/raw", 3)
    (parts / "fb_stage1.partial" / "fb_stage1").mkdir(parents=True)  # killed while writing
    assert merge_parts(parts, bag) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "fb_stage1.partial" in err and str(parts) in err, err
    assert _counts(bag) == {"/dcsms/sensors/raw": 3}
    assert (parts / "plant_simulator" / "metadata.yaml").exists()
