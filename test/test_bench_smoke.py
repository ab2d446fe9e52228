"""`bench/run.py --smoke` runs and writes well-formed results (no timing assertions)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_bench_smoke_writes_json(tmp_path):
    """The smoke run exits 0 and writes machine info plus rows with name, value and unit."""
    out = tmp_path / "results.json"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               DCSMS_BENCH_DOMAIN=str(150 + os.getpid() % 50))
    subprocess.run([sys.executable, str(ROOT / "bench" / "run.py"), "--smoke", "--out",
                    str(out)], check=True, env=env, timeout=600, capture_output=True)
    data = json.loads(out.read_text())
    assert {"cpu", "cores", "python", "numpy", "date"} <= data["machine"].keys()
    assert data["smoke"] is True
    assert data["rows"]
    for row in data["rows"]:
        assert {"name", "value", "unit", "bench", "verdict"} <= row.keys()
        assert row["value"] is None or isinstance(row["value"], (int, float))
    assert {r["bench"] for r in data["rows"]} >= {"engine", "bags"}
