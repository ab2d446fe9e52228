"""Mode names, which loops a mode closes, and controller ids."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcsms_ros.core.check import stability
from dcsms_ros.core.config import load_config
from dcsms_ros.core.modes import (
    ALL_MODES,
    FEEDBACK,
    FEEDFORWARD,
    ControllerId,
    Mode,
    controller_ids,
    enabled_controllers,
    parse_mode,
)
from dcsms_ros.errors import ConfigError, ModeError

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


@pytest.mark.parametrize(("text", "kind", "stage", "body"), [
    ("fb_stage1", FEEDBACK, 1, 1), ("fb_stage2", FEEDBACK, 2, 2), ("fb_stage12", FEEDBACK, 12, 12),
    ("ff_stage1", FEEDFORWARD, 1, 0)])
def test_controller_id_round_trip(text, kind, stage, body):
    """parse and str are inverse; kind, stage, the body it reads and its wrench frame."""
    cid = ControllerId.parse(text)
    assert cid == ControllerId(kind, stage)
    assert str(cid) == text
    assert ControllerId.parse(str(cid)) == cid
    assert cid.feedback is (kind == FEEDBACK)
    assert cid.sensed_body == body
    assert cid.frame == f"stage{stage}"
    assert ControllerId.is_valid(text)


@pytest.mark.parametrize("text", [
    "", "fb_stage", "fb_stage0", "fb_stage01", "fb_stage-1", "ff_stage2", "xx_stage1",
    "FB_STAGE1", "fb_stage1 ", " fb_stage1", "fb_stage1x", "fbstage1", "fb_stage1/enable",
    "fb_stage٣"])
def test_controller_id_rejects_other_strings(text):
    """Anything but fb_stage<i> (i >= 1, no leading zero) or ff_stage1 is a one-line
    ConfigError that quotes the string and names the valid forms."""
    with pytest.raises(ConfigError, match=r"unknown controller .*expected fb_stage<i> "
                       r"\(i >= 1\) or ff_stage1"):
        ControllerId.parse(text)
    assert not ControllerId.is_valid(text)


@pytest.mark.parametrize(("kind", "stage"), [("fb", 0), ("ff", 2), ("xx", 1), ("fb", 1.0),
                                             ("fb", True)])
def test_controller_id_constructor_validates(kind, stage):
    with pytest.raises(ConfigError, match="no controller"):
        ControllerId(kind, stage)


def test_controller_ids_sort_as_the_forces_are_summed():
    """Feedback first, by stage (numerically: stage 10 after stage 2), then feedforward: the
    order of controller_ids, which the plant and the batch engine sum in."""
    ids = controller_ids(10)
    parsed = [ControllerId.parse(c) for c in ids]
    shuffled = [parsed[i] for i in (5, 10, 0, 9, 1, 3, 2, 8, 4, 7, 6)]
    assert [str(c) for c in sorted(shuffled)] == list(ids)  # not the strings' order
    assert sorted(ids) != list(ids)
    assert ids[:2] == ("fb_stage1", "fb_stage2") and ids[-1] == "ff_stage1"
    assert len({*parsed, ControllerId(FEEDBACK, 1)}) == len(ids)  # frozen: hashable


def test_dual_modes_enable_every_feedback_stage():
    assert enabled_controllers(Mode.DFBC_FFC, 3) == {"fb_stage1", "fb_stage2", "fb_stage3",
                                                     "ff_stage1"}
    assert enabled_controllers(Mode.FBC, 3) == {"fb_stage1"}
