"""Truncated, corrupted or incomplete bags: `dcsms analyze` names the file, never a traceback."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from rel_harness import call, report


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 30 s batch-simulated bag, Passive then DFBC (two analysable segments)."""
    out = tmp_path_factory.mktemp("bag") / "good"
    r = call(["sim", "--duration", "30", "--mode", "passive", "--schedule", "15:dfbc",
              "--out", str(out)], timeout=300)
    assert r.returncode == 0, r.stderr
    return out


def _damage(good: Path, dst: Path, how: str) -> Path:
    shutil.copytree(good, dst)
    mcap = next(dst.glob("*.mcap"))
    data = mcap.read_bytes()
    if how == "truncated to 60 %":
        mcap.write_bytes(data[: int(len(data) * 0.6)])
    elif how == "truncated to 100 bytes":
        mcap.write_bytes(data[:100])
    elif how == "garbage in the middle":
        mid = len(data) // 2
        mcap.write_bytes(data[:mid] + b"\xde\xad\xbe\xef" * 4096 + data[mid + 16384:])
    elif how == "empty data file":
        mcap.write_bytes(b"")
    elif how == "no metadata.yaml":
        (dst / "metadata.yaml").unlink()
    elif how == "corrupt metadata.yaml":
        (dst / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    elif how == "data file missing":
        mcap.unlink()
    return dst


CASES = ["truncated to 60 %", "truncated to 100 bytes", "garbage in the middle",
         "empty data file", "no metadata.yaml", "corrupt metadata.yaml", "data file missing",
         "not a bag directory"]


def test_damaged_bags_give_one_line_errors_or_partial_analysis(good_bag, tmp_path):
    """Each damaged bag: a one-line error naming it (status 1 or 2) or analysis, no traceback."""
    ok = call(["analyze", str(good_bag)], timeout=300)
    assert ok.returncode == 0, ok.stderr
    outcome: dict[str, str] = {}
    for i, how in enumerate(CASES):
        bag = tmp_path / f"bag{i}"
        if how == "not a bag directory":
            bag.mkdir()
        else:
            _damage(good_bag, bag, how)
        r = call(["analyze", str(bag)], timeout=300)
        err = r.stderr.strip()
        assert "Traceback" not in r.stderr + r.stdout, f"{how}: {r.stderr}"
        if r.returncode == 0:
            outcome[how] = "analysed what is readable"
            assert "Passive" in r.stdout or "warning" in err, f"{how}: {r.stdout}"
        else:
            outcome[how] = f"exit {r.returncode}: {err}"
            assert r.returncode in (1, 2), f"{how}: exit {r.returncode}"
            lines = [ln for ln in err.splitlines() if not ln.startswith("warning:")]
            assert len(lines) == 1, f"{how}: not one line: {err}"
            assert str(bag) in lines[0] and lines[0].startswith("dcsms: error:"), f"{how}: {err}"
    report("8", f"{len(CASES)} damaged bags (truncated, garbage, missing files)",
           "no traceback; one-line error naming the bag, or analysis of the readable part",
           f"{sum(v.startswith('exit') for v in outcome.values())} refused, "
           f"{sum(not v.startswith('exit') for v in outcome.values())} analysed",
           outcome=outcome)
