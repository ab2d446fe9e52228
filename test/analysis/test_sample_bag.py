"""The shipped sample bag (recorded from the lockstep graph) analyses as docs/tem.md shows."""

from __future__ import annotations

from pathlib import Path

from dcsms_ros.analysis.report import analyze
from dcsms_ros.cli import main

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample"


def test_sample_bag_gives_the_passive_and_dfbc_ffc_rows(tmp_path):
    """Two segments, the recorded configuration, DFBC+FFC at or below 0.1 of Passive in Z."""
    summary = analyze([SAMPLE], out_dir=tmp_path)
    z = {s["mode"]: s["axes"]["z"]["normalized"] for s in summary.segments}
    assert list(z) == ["Passive", "DFBC+FFC"]
    assert z["Passive"] == 1.0 and 0.0 < z["DFBC+FFC"] <= 0.1
    assert summary.config_source.endswith("/dcsms/config")
    assert 3.5 < summary.resonance_hz["z"] < 4.1  # the 3.77 Hz mode within the Welch resolution
    assert (tmp_path / "report.md").exists()


def test_readme_command_on_the_sample_bag(tmp_path, capsys):
    """`dcsms analyze bags/sample --json` exits 0 with the mode table in JSON."""
    assert main(["analyze", str(SAMPLE), "--out", str(tmp_path), "--json"]) == 0
    assert '"DFBC+FFC"' in capsys.readouterr().out
