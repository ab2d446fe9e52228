"""Mode names and which loops a mode closes."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcsms_ros.core.check import stability
from dcsms_ros.core.config import load_config
from dcsms_ros.core.modes import ALL_MODES, Mode, parse_mode
from dcsms_ros.errors import ModeError

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(("name", "mode"), [
    ("DFBC+FFC", Mode.DFBC_FFC), ("dfbc_ffc", Mode.DFBC_FFC), ("FFC + DFBC", Mode.DFBC_FFC),
    ("fbc-ffc", Mode.FBC_FFC), ("passive", Mode.PASSIVE)])
def test_parse_mode_spellings(name, mode):
    assert parse_mode(name) is mode


def test_unknown_mode_lists_the_valid_ones():
    with pytest.raises(ModeError, match="valid modes: Passive, FBC, FFC"):
        parse_mode("warp")


def test_open_loop_modes_are_stable_even_where_feedback_is_not():
    """`Mode.feedback` is False exactly for Passive and FFC, and the loop model agrees that those
    stay stable with the unstable fixture, whose feedback modes are not."""
    assert [m for m in ALL_MODES if not m.feedback] == [Mode.PASSIVE, Mode.FFC]
    cfg = load_config(ROOT / "test" / "fixtures" / "tem_unstable.yaml")
    assert not stability(cfg, Mode.DFBC).stable
    for m in (Mode.PASSIVE, Mode.FFC):
        assert stability(cfg, m).stable
