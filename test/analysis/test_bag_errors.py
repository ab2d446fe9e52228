"""Damaged or missing bags give one clean BagError naming the file."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from synth_bag import write_bag

from dcsms_ros.analysis.reader import read_bag
from dcsms_ros.analysis.report import analyze
from dcsms_ros.errors import BagError


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_bag(tmp_path_factory.mktemp("b") / "bag", seconds=6.0,
                     modes=(("Passive", 0.0, 0.0),))


def test_truncated_mcap_is_a_bag_error(small_bag: Path, tmp_path: Path) -> None:
    """Cutting the MCAP file in half gives BagError naming the bag, not a traceback."""
    bad = tmp_path / "cut"
    shutil.copytree(small_bag, bad)
    f = bad / "bag.mcap"
    data = f.read_bytes()
    f.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=str(bad)):
        analyze([bad])


def test_garbage_storage_is_a_bag_error(small_bag: Path, tmp_path: Path) -> None:
    """A storage file overwritten with garbage gives BagError naming the bag."""
    bad = tmp_path / "garbage"
    shutil.copytree(small_bag, bad)
    (bad / "bag.mcap").write_bytes(b"\x00garbage" * 100)
    with pytest.raises(BagError, match=str(bad)):
        read_bag(bad)


def test_missing_bag_and_metadata(small_bag: Path, tmp_path: Path) -> None:
    """A missing path or a bag without metadata.yaml gives BagError naming it."""
    with pytest.raises(BagError, match="nothere"):
        read_bag(tmp_path / "nothere")
    bad = tmp_path / "nometa"
    shutil.copytree(small_bag, bad)
    (bad / "metadata.yaml").unlink()
    with pytest.raises(BagError, match=str(bad)):
        read_bag(bad)
