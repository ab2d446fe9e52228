"""A bag whose writer did not close it is recovered up to its last whole chunk: every message
of the chunks that reached the file, in order, nothing of a chunk cut off or damaged; a real
process killed with SIGKILL; the unmerged parts of a per-process recording."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis import mcapwrite
from dcsms_ros.analysis.bagrecover import recover_parts, recover_unfinished, unfinished_parts
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.cli import main as dcsms
from dcsms_ros.errors import BagError

TOPICS = ("/dcsms/velocity/stage1", "/dcsms/mode")
#: One message record: 31 bytes of header and 16 of data; a chunk of this many bytes holds 10.
RECORD = 47
PER_CHUNK = 10


def _message(k: int) -> tuple[str, int, bytes]:
    """Message ``k`` of a test recording: topic, log time (ns), 16 distinct bytes."""
    return TOPICS[k % 2], 1_000 + 500_000 * k, k.to_bytes(8, "little") * 2


def _read(bag: Path) -> list[tuple[str, int, bytes]]:
    with Reader(bag) as r:
        return [(c.topic, t, bytes(raw)) for c, t, raw in r.messages()]


def _stage(tmp: Path, name: str, data: bytes) -> Path:
    """An unfinished bag ``name`` (its staging directory) holding ``data`` as its file."""
    inner = tmp / f"{name}.partial" / name
    inner.mkdir(parents=True)
    (inner / f"{name}.mcap").write_bytes(data)
    return tmp / name


@pytest.fixture(scope="module")
def snapshots(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[bytes], bytes, int]:
    """What a writer killed after its k-th flush leaves (k = 0..5, each flush writing one
    chunk of 10 messages), and its closed file with every one of its ``n`` messages."""
    out = tmp_path_factory.mktemp("snap") / "bag"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mcapwrite, "CHUNK_MAX_AGE_S", 1e9)  # chunks close when full only
        w = McapBagWriter(out, chunk_bytes=PER_CHUNK * RECORD, defer_flush=True)
        for t in TOPICS:
            w.add_topic(t, cdr.HEADER)
        w.flush()
        snaps = [w.file.read_bytes()]
        n = 0
        for k in range(1, 6):
            while n < PER_CHUNK * k + 1:  # the 11th message of a chunk closes it
                w.write(*_message(n))
                n += 1
            w.flush()
            snaps.append(w.file.read_bytes())
        for _ in range(7):
            w.write(*_message(n))
            n += 1
        w.close()
    return snaps, (out / "bag.mcap").read_bytes(), n


@pytest.mark.parametrize("k", range(6))
def test_a_killed_writer_keeps_every_chunk_it_wrote(tmp_path: Path, snapshots, k: int) -> None:
    snaps, _, _ = snapshots
    rec = recover_unfinished(_stage(tmp_path, "bag", snaps[k]))
    assert _read(tmp_path / "bag") == [_message(i) for i in range(PER_CHUNK * k)]
    assert rec.counts == dict.fromkeys(TOPICS, PER_CHUNK * k // 2) and rec.lost_bytes == 0
    assert not (tmp_path / "bag.partial").exists() and not (tmp_path / "bag.recovering").exists()


@pytest.mark.parametrize("k", range(1, 6))
@pytest.mark.parametrize("cut", [1, 9, 20, 100])
def test_a_chunk_cut_off_is_lost_whole(tmp_path: Path, snapshots, k: int, cut: int) -> None:
    """Cut ``cut`` bytes into chunk k's record (it starts where the file of flush k - 1
    ended; 1 and 9: inside its opcode and length; every chunk here is longer than 100)."""
    snaps, _, _ = snapshots
    data = snaps[k][:len(snaps[k - 1]) + cut]
    rec = recover_unfinished(_stage(tmp_path, "bag", data))
    assert _read(tmp_path / "bag") == [_message(i) for i in range(PER_CHUNK * (k - 1))]
    assert rec.lost_bytes == cut


@pytest.mark.parametrize("k", range(1, 6))
def test_a_cut_after_the_chunk_keeps_it(tmp_path: Path, snapshots, k: int) -> None:
    """Cut 1 byte before the end: only the last message index (< 100 bytes) is cut."""
    snaps, _, _ = snapshots
    rec = recover_unfinished(_stage(tmp_path, "bag", snaps[k][:-1]))
    assert _read(tmp_path / "bag") == [_message(i) for i in range(PER_CHUNK * k)]
    assert 0 < rec.lost_bytes < 100


def test_zeros_after_the_last_chunk_are_dropped(tmp_path: Path, snapshots) -> None:
    """A crash can leave the file's last blocks zero-filled."""
    snaps, _, _ = snapshots
    rec = recover_unfinished(_stage(tmp_path, "bag", snaps[3] + bytes(4096)))
    assert rec.messages == 3 * PER_CHUNK and rec.lost_bytes == 4096


def test_a_damaged_chunk_ends_the_recovery(tmp_path: Path, snapshots) -> None:
    snaps, _, _ = snapshots
    data = bytearray(snaps[4])
    data[len(snaps[2]) + 70] ^= 0xFF  # inside chunk 3's compressed bytes
    rec = recover_unfinished(_stage(tmp_path, "bag", bytes(data)))
    assert _read(tmp_path / "bag") == [_message(i) for i in range(2 * PER_CHUNK)]
    assert rec.lost_bytes == len(data) - len(snaps[2])


def test_a_closed_file_without_metadata_gives_every_message(tmp_path: Path, snapshots) -> None:
    """Killed between the file's footer and ``metadata.yaml``: the summary is not data."""
    _, closed, n = snapshots
    rec = recover_unfinished(_stage(tmp_path, "bag", closed))
    assert _read(tmp_path / "bag") == [_message(i) for i in range(n)] and rec.lost_bytes == 0


def test_a_writer_killed_before_writing_leaves_an_empty_bag(tmp_path: Path) -> None:
    (tmp_path / "bag.partial" / "bag").mkdir(parents=True)
    assert recover_unfinished(tmp_path / "bag").messages == 0
    assert _read(tmp_path / "bag") == []


@pytest.mark.parametrize(("setup", "message"), [
    ("none", "no unfinished bag to recover"),
    ("exists", "exists already"),
    ("not_mcap", "not an MCAP file"),
    ("sqlite", "only MCAP bags can be recovered"),
])
def test_what_cannot_be_recovered_is_refused_and_kept(tmp_path: Path, setup: str,
                                                      message: str) -> None:
    out = tmp_path / "bag"
    if setup == "exists":
        out.mkdir()
    elif setup == "not_mcap":
        _stage(tmp_path, "bag", b"not a bag at all")
    elif setup == "sqlite":
        inner = tmp_path / "bag.partial" / "bag"
        inner.mkdir(parents=True)
        (inner / "bag_0.db3").write_bytes(b"SQLite format 3\x00")
    with pytest.raises(BagError, match=message):
        recover_unfinished(out)
    if setup in ("not_mcap", "sqlite"):  # the input stays, under the name of a recovery
        assert (tmp_path / "bag.recovering" / "bag").is_dir()
        assert not out.exists() and not (tmp_path / "bag.partial").exists()


def test_chunks_older_than_the_limit_reach_the_file(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A deferred writer's flush closes its open chunk once it is CHUNK_MAX_AGE_S old (here
    0), so a slow topic's messages are on disk, not only in the writer's memory."""
    monkeypatch.setattr(mcapwrite, "CHUNK_MAX_AGE_S", 0.0)
    w = McapBagWriter(tmp_path / "live" / "bag", defer_flush=True)
    w.add_topic(TOPICS[1], cdr.HEADER)
    w.write(*_message(1))
    w.flush()
    data = w.file.read_bytes()
    w.abort()
    recover_unfinished(_stage(tmp_path, "bag", data))
    assert _read(tmp_path / "bag") == [_message(1)]


#: Writes 500 messages, flushes them (chunks closed at once), writes 300 more that stay in
#: its open chunk, then kills itself.
KILLED = """
import os, signal, sys
from pathlib import Path
from dcsms_ros import cdr
from dcsms_ros.analysis import mcapwrite
sys.path.insert(0, sys.argv[2])
from test_bagrecover import TOPICS, _message
mcapwrite.CHUNK_MAX_AGE_S = 0.0
w = mcapwrite.McapBagWriter(Path(sys.argv[1]), defer_flush=True)
for t in TOPICS:
    w.add_topic(t, cdr.HEADER)
for k in range(500):
    w.write(*_message(k))
w.flush()
for k in range(500, 800):
    w.write(*_message(k))
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_process_killed_while_recording(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """A real writer process killed with SIGKILL; `dcsms recover` gives back what it had
    flushed, says what was lost, and removes the leftover."""
    out = tmp_path / "bag"
    proc = subprocess.run([sys.executable, "-c", KILLED, str(out), str(Path(__file__).parent)],
                          check=False, capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert (tmp_path / "bag.partial").is_dir() and not out.exists()
    assert dcsms(["recover", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["counts"] == dict.fromkeys(TOPICS, 250)
    assert report["recovered"] == {"bag": {"messages": 500, "lost_bytes": 0}}
    assert _read(out) == [_message(k) for k in range(500)]
    assert not (tmp_path / "bag.partial").exists()
    assert dcsms(["recover", str(out)]) == 2  # nothing left to recover, and OUT exists
    assert "exists already" in capsys.readouterr().err


def test_parts_left_unmerged_are_recovered_and_merged(tmp_path: Path, snapshots,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    """`dcsms up --record` killed: its parts stay in OUT.parts, one of them unfinished."""
    snaps, _, _ = snapshots
    out = tmp_path / "run"
    parts = tmp_path / "run.parts"
    parts.mkdir()
    closed = McapBagWriter(parts / "recorder")
    closed.add_topic("/dcsms/config", cdr.HEADER)
    closed.write("/dcsms/config", 5, bytes(16))
    closed.close()
    _stage(parts, "plant_simulator", snaps[2])
    assert unfinished_parts(parts) == ["plant_simulator"]
    assert dcsms(["recover", str(out)]) == 0
    text = capsys.readouterr().out
    assert "21 messages on 3 topics" in text and "plant_simulator: not closed; 20" in text, text
    assert len(_read(out)) == 21 and not parts.exists()


def test_recover_parts_in_place(tmp_path: Path, snapshots) -> None:
    snaps, _, _ = snapshots
    _stage(tmp_path, "a", snaps[1])
    _stage(tmp_path, "b", snaps[0])
    got = recover_parts(tmp_path)
    assert {k: v.messages for k, v in got.items()} == {"a": 10, "b": 0}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]
