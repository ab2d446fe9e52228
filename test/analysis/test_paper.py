"""The report compares the mode table with the paper's Table 4 for a TEM (6-DOF) bag, or on
request."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dcsms_ros.analysis.export import write_result_bag
from dcsms_ros.analysis.paper import TABLE4, comparison, within
from dcsms_ros.analysis.report import analyze
from dcsms_ros.cli import main
from dcsms_ros.core.config import load_config
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode

ROOT = Path(__file__).resolve().parents[2]


def test_comparison_rows_and_count():
    """Ratios are ours / paper; None where we have no value; the +-30 % count uses them."""
    rows = comparison({"FBC": {"x": 0.243 * 1.2, "y": None, "z": 0.873 * 0.5}}, ["x", "y", "z"])
    assert [(r["mode"], r["axis"]) for r in rows] == [("FBC", "x"), ("FBC", "y"), ("FBC", "z")]
    assert rows[0]["ratio"] == pytest.approx(1.2) and rows[1]["ratio"] is None
    assert within(rows) == 1
    assert set(TABLE4) == {"Passive", "FBC", "FBC+FFC", "DFBC", "DFBC+FFC"}


@pytest.mark.slow
def test_tem_bag_report_has_the_paper_section(tmp_path):
    """A 6-DOF bag: summary and report.md hold the paper, ours and the ratio per axis."""
    cfg = load_config(ROOT / "config" / "tem_three_point.yaml")
    res = simulate(cfg, Mode.PASSIVE, 26.0, schedule=[(13.0, Mode.DFBC)], seed=6)
    bag = tmp_path / "bag"
    write_result_bag(res, bag)
    summary = analyze([bag], out_dir=tmp_path / "out")
    rows = {(r["mode"], r["axis"]): r for r in summary.paper or []}
    assert set(rows) == {("DFBC", a) for a in "xyz"}
    seg = next(s for s in summary.segments if s["mode"] == "DFBC")
    for a in "xyz":
        r = rows[("DFBC", a)]
        assert r["paper"] == TABLE4["DFBC"][a]
        assert r["ours"] == pytest.approx(seg["axes"][a]["normalized"])
        assert r["ratio"] == pytest.approx(r["ours"] / r["paper"])
    md = (tmp_path / "out" / "report.md").read_text()
    assert "## Paper comparison" in md and "| DFBC | y | 0.751 |" in md
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert len(doc["paper_comparison"]) == 3


@pytest.mark.slow
def test_paper_flag_on_a_1dof_bag(tmp_path, capsys):
    """--paper compares a 1-DOF bag in Z; without it, no comparison."""
    cfg = load_config(ROOT / "config" / "table1.yaml")
    res = simulate(cfg, Mode.PASSIVE, 24.0, schedule=[(12.0, Mode.FBC)], seed=2)
    bag = tmp_path / "bag"
    write_result_bag(res, bag)
    assert analyze([bag]).paper is None
    status = main(["analyze", str(bag), "--paper", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert status == 0
    assert [(r["mode"], r["axis"]) for r in doc["paper_comparison"]] == [("FBC", "z")]
