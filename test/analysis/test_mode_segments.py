"""Mode segmentation, settle time, label placement and the recorded-config round trip."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from synth_bag import write_bag

from dcsms_ros.analysis.reader import ModeEvent, config_from_yaml, config_to_yaml, read_bag
from dcsms_ros.analysis.segments import align, split_segments
from dcsms_ros.core.config import load_config
from dcsms_ros.core.modes import Mode

S = 1_000_000_000


def test_split_drops_settle_after_each_switch() -> None:
    """Each window starts settle_s after its switch and ends at the next switch."""
    ev = [ModeEvent(0, 0, "Passive"), ModeEvent(0, 10 * S, "FBC"),
          ModeEvent(0, 25 * S, "dfbc_ffc")]
    segs = split_segments(ev, 0, 40 * S - 1, settle_s=1.5)
    assert [s.label for s in segs] == ["Passive", "FBC", "dfbc_ffc"]
    assert [s.mode for s in segs] == [Mode.PASSIVE, Mode.FBC, Mode.DFBC_FFC]
    assert [(s.t0_ns, s.t1_ns) for s in segs] == [(0, 10 * S), (int(11.5 * S), 25 * S),
                                                  (int(26.5 * S), 40 * S)]
    unknown = split_segments([], 5, 99)
    assert len(unknown) == 1 and unknown[0].mode is None


def test_settle_per_mode_and_from_rest() -> None:
    """A settle time per mode label (others 1 s); a run from rest loses it at the start too."""
    ev = [ModeEvent(0, 0, "Passive"), ModeEvent(0, 10 * S, "FBC"), ModeEvent(0, 25 * S, "DFBC")]
    segs = split_segments(ev, 0, 40 * S - 1, {"Passive": 6.0, "FBC": 2.5}, from_rest=True)
    assert [(s.t0_ns, s.t1_ns) for s in segs] == [(6 * S, 10 * S), (int(12.5 * S), 25 * S),
                                                  (26 * S, 40 * S)]


def test_bag_modes_and_config(tmp_path: Path) -> None:
    """read_bag places switches on the data's time axis and returns the recorded config."""
    modes = (("Passive", 0.0, 0.0), ("FBC", 1e4, 0.0))
    bag = write_bag(tmp_path / "bag", fs=200.0, seconds=6.0, modes=modes)
    data = read_bag(bag)
    assert [m.label for m in data.modes] == ["Passive", "FBC"]
    assert data.modes[1].stamp_ns - data.modes[0].stamp_ns == 6 * S
    assert set(data.bodies) == {"ground", "stage1", "stage2"}
    assert data.applied is not None and data.applied.columns == ("stage1", "stage2")
    segs = split_segments(data.modes, int(data.bodies["ground"].stamp_ns[0]),
                          int(data.bodies["ground"].stamp_ns[-1]))
    al = align(data, segs[1])
    assert al.fs == 200.0 and al.missing == 0 and al.stamp_ns.size == 5 * 200
    assert np.all(al.bodies["stage1"][:, :2] == 0)
    cfg = config_from_yaml(data.config_text or "")
    assert cfg.params == load_config().params


def test_config_yaml_round_trip() -> None:
    """config_to_yaml -> config_from_yaml gives the same flat parameters (6dof too)."""
    cfg = load_config()
    assert config_from_yaml(config_to_yaml(cfg)).params == cfg.params


def test_align_drops_samples_missing_in_one_topic(tmp_path: Path) -> None:
    """A sample dropped by one topic is removed from every body; the others stay aligned."""
    bag = write_bag(tmp_path / "bag", fs=200.0, seconds=6.0, modes=(("Passive", 0.0, 0.0),))
    data = read_bag(bag)
    seg = split_segments(data.modes, int(data.bodies["ground"].stamp_ns[0]),
                         int(data.bodies["ground"].stamp_ns[-1]))[0]
    full = align(data, seg)
    s1 = data.bodies["stage1"]
    keep = np.ones(s1.stamp_ns.size, bool)
    keep[[300, 301, 700]] = False
    s1.stamp_ns, s1.values = s1.stamp_ns[keep], s1.values[keep]
    al = align(data, seg)
    assert al.stamp_ns.size == full.stamp_ns.size - 3 and al.missing == 3
    gone = np.isin(full.stamp_ns, al.stamp_ns)
    for body in ("ground", "stage1", "stage2"):
        np.testing.assert_array_equal(al.bodies[body], full.bodies[body][gone])
