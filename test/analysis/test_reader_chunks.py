"""Chunk-level MCAP reading (mcapchunks) against the rosbags message-by-message path."""

from __future__ import annotations

import numpy as np
import pytest
from synth_bag import write_bag

from dcsms_ros.analysis import mcapchunks, reader
from dcsms_ros.analysis.reader import read_bag


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp("chunks") / "bag", fs=500.0, seconds=6.0)


def _both(bag, monkeypatch):
    fast = read_bag(bag)
    with monkeypatch.context() as m:
        m.setattr(reader, "_read_chunks", lambda *a: False)
        slow = read_bag(bag)
    return fast, slow


def test_chunk_reader_equals_rosbags_path(bag, monkeypatch):
    """Every array, mode event, config text and count is identical on both paths."""
    fast, slow = _both(bag, monkeypatch)
    assert fast.bodies.keys() == slow.bodies.keys()
    for body in fast.bodies:
        a, b = fast.bodies[body], slow.bodies[body]
        np.testing.assert_array_equal(a.stamp_ns, b.stamp_ns)
        np.testing.assert_array_equal(a.values, b.values)
        assert (a.log_ns is None) == (b.log_ns is None)
        if a.log_ns is not None:
            np.testing.assert_array_equal(a.log_ns, b.log_ns)
        assert (a.columns, a.frame_id) == (b.columns, b.frame_id)
    np.testing.assert_array_equal(fast.applied.values, slow.applied.values)
    assert fast.applied.columns == slow.applied.columns
    assert fast.modes == slow.modes
    assert fast.config_text == slow.config_text
    assert fast.counts == slow.counts and fast.warnings == slow.warnings


def test_chunk_reader_is_used_for_mcap(bag, monkeypatch):
    """An indexed MCAP bag goes through the chunk reader, not rosbags' message iterator."""
    seen = []
    orig = mcapchunks.iter_blocks
    monkeypatch.setattr(mcapchunks, "iter_blocks", lambda *a, **k: seen.append(1) or orig(*a, **k))
    read_bag(bag)
    assert seen


def test_truncated_mcap_raises_bag_error(bag, tmp_path):
    """A cut-off MCAP file is a BagError naming the bag, as on the rosbags path."""
    import shutil

    from dcsms_ros.errors import BagError

    cut = tmp_path / "cut"
    shutil.copytree(bag, cut)
    f = next(cut.glob("*.mcap"))
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match="cut"):
        read_bag(cut)


def test_a_repeated_sample_is_read_once(bag, tmp_path, monkeypatch):
    """Lockstep retransmissions record a sample twice in a row (same stamp, same numbers): both
    paths read it once, so the bag equals the one without repeats."""
    again = write_bag(tmp_path / "again", fs=500.0, seconds=6.0, repeat=(0, 499, 1500, 2999))
    clean = read_bag(bag)
    for got in _both(again, monkeypatch):
        for body in clean.bodies:
            np.testing.assert_array_equal(got.bodies[body].stamp_ns, clean.bodies[body].stamp_ns)
            np.testing.assert_array_equal(got.bodies[body].values, clean.bodies[body].values)
        np.testing.assert_array_equal(got.applied.values, clean.applied.values)
        assert got.modes == clean.modes
