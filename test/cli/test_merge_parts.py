"""dcsms up's merge of a per-process recording's parts: the bag from every finished part; a
part left unfinished (its process killed) is read back up to its last whole chunk, named, and
fails the run; a part that cannot be read keeps them all."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from dcsms_ros import cdr
from dcsms_ros.analysis import mcapwrite
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.cli.parts import RECORDER_PART, merge_parts, parts_dir


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


def test_an_unfinished_part_is_recovered_named_and_merged(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A part its process did not close: read back up to its last whole chunk (here: the
    first of two; the second is cut off), merged with the others, and named; the run fails."""
    bag = tmp_path / "run"
    parts = parts_dir(bag)
    _part(parts / "plant_simulator", "/dcsms/sensors/raw", 3)
    monkeypatch.setattr(mcapwrite, "CHUNK_MAX_AGE_S", 1e9)  # chunks close when full only
    killed = McapBagWriter(tmp_path / "killed", chunk_bytes=64, defer_flush=True)
    killed.add_topic("/dcsms/force/fb_stage1", cdr.HEADER)
    for k in range(2):
        killed.write("/dcsms/force/fb_stage1", k, bytes(16))
    killed.flush()  # the second message closed the first chunk
    data = killed.file.read_bytes()
    killed.abort()
    inner = parts / "fb_stage1.partial" / "fb_stage1"
    inner.mkdir(parents=True)
    (inner / "fb_stage1.mcap").write_bytes(data + b"\x06\x10")  # a chunk cut off after 2 bytes
    assert merge_parts(parts, bag) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "fb_stage1's part of the bag was not closed" in err, err
    assert "recovered 1 messages" in err and "2 bytes cut off" in err, err
    assert _counts(bag) == {"/dcsms/sensors/raw": 3, "/dcsms/force/fb_stage1": 1}
    assert not parts.exists()


def test_a_part_that_cannot_be_read_keeps_them_all(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "run"
    parts = parts_dir(bag)
    _part(parts / "plant_simulator", "/dcsms/sensors/raw", 3)
    inner = parts / "fb_stage1.partial" / "fb_stage1"
    inner.mkdir(parents=True)
    (inner / "fb_stage1.mcap").write_bytes(b"garbage")
    assert merge_parts(parts, bag) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an MCAP file" in err and f"dcsms recover {bag}" in err
    assert not bag.exists() and (parts / "plant_simulator" / "metadata.yaml").exists()
