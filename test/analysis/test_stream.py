"""The streaming batch path: the same messages as simulate() + export, block boundaries and a
trip included; every reader sees the same counts; hopeless runs refused before writing."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from burst import burst_floor, supervisor
from rosbags.rosbag2 import Reader

from dcsms_ros.analysis import stream
from dcsms_ros.analysis.export import write_result_bag
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.analysis.reader import read_bag
from dcsms_ros.cli import main
from dcsms_ros.cli.common import default_config_path
from dcsms_ros.core import topics
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.engine import Simulation, simulate
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.supervisor import State
from dcsms_ros.errors import BagError, DcsmsError

CFG = load_config(default_config_path())
SCHEDULE = [(0.3, Mode.PASSIVE), (0.61, Mode.FBC)]


def _messages(bag: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with Reader(bag) as r:
        for c, t, raw in r.messages():
            out.setdefault(c.topic, []).append((t, bytes(raw)))
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_stream_equals_simulate_and_export(tmp_path: Path, storage: str) -> None:
    """1 s in 0.25 s blocks (switches inside and on a block edge) gives the same messages,
    log times and order per topic as one simulate() exported at once."""
    res = simulate(CFG, Mode.DFBC_FFC, 1.0, seed=3, schedule=SCHEDULE)
    write_result_bag(res, tmp_path / "ref")
    got = stream.stream_bag(CFG, Mode.DFBC_FFC, 1.0, tmp_path / "streamed", seed=3,
                            schedule=SCHEDULE, storage=storage, block_s=0.25)
    ref, mine = _messages(tmp_path / "ref"), _messages(tmp_path / "streamed")
    assert sorted(mine) == sorted(ref)
    for topic in ref:
        assert mine[topic] == ref[topic], topic
    assert got.counts == {t: len(m) for t, m in ref.items()}
    assert not (tmp_path / "streamed.partial").exists()


@pytest.mark.parametrize(("storage", "block_s"), [("mcap", 1.05), ("sqlite3", 0.3)])
def test_supervisor_transitions_stream_as_exported(tmp_path: Path, storage: str,
                                                   block_s: float) -> None:
    """The floor x3000 from 1 to 2 s: RIDE_THROUGH at the checkpoint ending at sample 2099
    (with 1.05 s blocks the last of the first block, its FBC the next block's first sample);
    every message, supervisor/state included, equals the one-shot export's."""
    ground = burst_floor(CFG, 4.0, 1.0, 2.0)
    res = Simulation(CFG, Mode.DFBC_FFC, ground=ground,
                     supervisor=supervisor(CFG, Mode.DFBC_FFC)).run(int(4.0 * CFG.plant.rate_hz))
    assert res is not None
    assert [(tr.sample, tr.state) for tr in res.supervision] == [(2099, State.RIDE_THROUGH)]
    write_result_bag(res, tmp_path / "ref")
    # the supervisor stream_bag builds from the configuration decides the same
    got = stream.stream_bag(CFG, Mode.DFBC_FFC, 4.0, tmp_path / "s", ground=ground,
                            storage=storage, block_s=block_s)
    assert got.supervision == res.supervision
    ref = _messages(tmp_path / "ref")
    assert len(ref[topics.SUPERVISOR_STATE]) == 1
    assert _messages(tmp_path / "s") == ref
    assert got.counts == {t: len(m) for t, m in ref.items()}


def test_a_trip_on_a_block_edge_is_written_once(tmp_path: Path) -> None:
    """The stage-2 gain x50 trips at sample 99; its Passive falls on sample 100, the first
    of the second 0.05 s block: the mode messages equal the one-shot export's."""
    gain = [50.0 * g for g in CFG.params["feedback.stage2.gain"]]
    bad = with_overrides(CFG, {"feedback.stage2.gain": gain})
    res = simulate(bad, Mode.DFBC, 0.2)
    assert res.mode == [(0, "DFBC"), (100, "Passive")]
    write_result_bag(res, tmp_path / "ref")
    got = stream.stream_bag(bad, Mode.DFBC, 0.2, tmp_path / "s", block_s=0.05)
    first = got.supervision[0]  # the supervisor (on by default) trips there
    assert first.state is State.TRIPPED and first.sample == 99
    assert _messages(tmp_path / "s") == _messages(tmp_path / "ref")


@pytest.mark.slow
def test_every_reader_sees_the_same_counts(tmp_path: Path) -> None:
    """rosbags, the mcap library (decoding every message with mcap_ros2) and our chunk reader
    agree with the writer's counts; chunks are zstd with message indexes and a summary."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag = tmp_path / "b"
    got = stream.stream_bag(CFG, Mode.FBC, 3.0, bag, block_s=1.0)
    with Reader(bag) as r:
        rosbags = Counter(c.topic for c, _, _ in r.messages())
        meta = {c.topic: c.msgcount for c in r.connections}
    mc: Counter[str] = Counter()
    with next(bag.glob("*.mcap")).open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        for _, channel, _, msg in reader.iter_decoded_messages():
            mc[channel.topic] += 1
            assert msg is not None
    assert dict(rosbags) == meta == dict(mc) == got.counts
    assert got.counts[topics.velocity_topic("stage2")] == 6000
    data = read_bag(bag)
    assert data.counts == got.counts


def test_hopeless_runs_are_refused_before_writing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """An absurd duration, or a bag larger than the free space: one line, exit 2, no file."""
    out = tmp_path / "never"
    assert main(["sim", "--duration", "1e9", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--duration 1e+09" in err and "Traceback" not in err, err
    with pytest.raises(DcsmsError, match="GB free"):
        monkeypatch.setattr(stream.shutil, "disk_usage", lambda p: type(
            "U", (), {"free": 1_000_000})())
        stream.check_run(CFG, 600.0, out)
    assert not out.exists() and not out.with_name("never.partial").exists()


def test_a_failing_writer_leaves_nothing(tmp_path: Path) -> None:
    """An error while writing aborts the bag: neither OUT nor OUT.partial remains."""
    out = tmp_path / "x"
    w = McapBagWriter(out)
    w.add_topic(topics.MODE, "std_msgs/msg/String")
    with pytest.raises(BagError, match="not added"):
        w.write("/nope", 0, b"")
    w.abort()
    assert not out.exists() and not out.with_name("x.partial").exists()
    assert np.isfinite(stream.bytes_per_sample(CFG))
