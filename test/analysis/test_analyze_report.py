"""End to end: a synthetic multi-mode bag -> report.md, PNGs, summary.json, Table 4, CLI."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import pytest
from synth_bag import write_bag

from dcsms_ros.analysis.report import analyze
from dcsms_ros.cli import main

# every test here reads bags of 20-60 s runs made by session fixtures
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_bag(tmp_path_factory.mktemp("e2e") / "bag")


def test_analyze_writes_report_and_orders_table4(bag: Path, tmp_path: Path) -> None:
    """More damping gives a smaller normalised stage-2 velocity; all outputs are written."""
    out = tmp_path / "out"
    s = analyze([bag], out_dir=out)
    doc = json.loads((out / "summary.json").read_text())
    modes = [seg["mode"] for seg in doc["segments"]]
    assert modes == ["Passive", "FBC", "DFBC", "DFBC+FFC"]
    norm = [seg["axes"]["z"]["normalized"] for seg in doc["segments"]]
    assert norm[0] == 1.0 and all(a > b for a, b in itertools.pairwise(norm))
    assert doc["segments"][3]["axes"]["z"]["attenuation_db"] > 20
    assert 3.5 < doc["resonance_hz"]["z"] < 4.0  # the 3.77 Hz mode of Table 1
    for name in ("report.md", "summary.json", "transmissibility_z.png", "asd_z.png",
                 "third_octave_z.png"):
        assert (out / name).stat().st_size > 500, name
    md = (out / "report.md").read_text()
    assert "| DFBC+FFC |" in md and "VC-" in md
    passive = doc["segments"][0]["axes"]["z"]
    model = passive["model"]["transmissibility"]["stage2"]  # the loop model overlays Passive
    assert model["compared_bins"] > 50
    assert model["max_abs_error_db"] < 3.0
    assert passive["estimates"]["transmissibility"]["status"] == "estimated"
    assert passive["estimates"]["mobility"]["status"] == "unavailable"
    assert passive["model"]["mobility"] is None
    assert {"stage1", "stage2"} == set(passive["vc"])
    forces = doc["segments"][1]["forces"]
    assert forces[0]["rms_n"] > 0 and forces[0]["limit_n"] == 400.0  # 4 coils x 100 N
    assert "DFBC+FFC" in s.table()
    # every normalised value has its 95 % interval (the reference's is the value itself), and
    # each segment says how long after its switch it starts (the model's settle time)
    for seg in doc["segments"]:
        lo, hi = seg["axes"]["z"]["normalized_ci"]
        assert lo <= seg["axes"]["z"]["normalized"] <= hi and seg["axes"]["z"]["band_dof"] > 2
        assert seg["settled_s"] >= 0.0
    assert doc["segments"][0]["axes"]["z"]["normalized_ci"] == [1.0, 1.0]
    assert all(seg["settled_s"] >= 1.0 for seg in doc["segments"][1:])
    assert "95 % interval" in md and "95 % CI" in s.table()


def test_cli_prints_mode_table_and_json(bag: Path, capsys: pytest.CaptureFixture) -> None:
    """`dcsms analyze` prints the mode table; --json prints the summary; bad bag exits 2."""
    from dcsms_ros.cli import main

    assert main(["analyze", str(bag)]) == 0
    text = capsys.readouterr().out
    assert "Passive" in text and "DFBC+FFC" in text and "Z norm" in text
    assert main(["analyze", str(bag), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["reference"] == "Passive"
    assert main(["analyze", str(bag.parent / "missing")]) == 2
    assert "missing" in capsys.readouterr().err


@pytest.mark.parametrize("settle", ["-1", "nan", "inf"])
def test_bad_settle_is_a_usage_error(settle: str, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A negative settle would analyse the previous mode's samples as the new mode's; NaN
    crashed the segment split. Refused before any bag is read or anything written."""
    assert main(["analyze", str(tmp_path / "bag"), "--settle", settle,
                 "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err == f"dcsms: error: settle {float(settle):g} s: must be finite and >= 0\n"
    assert not (tmp_path / "o").exists()
