"""`bench/run.py --smoke` runs and writes well-formed results (no timing assertions)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from rosdomains import lease_domains

ROOT = Path(__file__).resolve().parents[1]
# the smoke run starts the graph (ping-pong, lockstep) in domains of its own: bench/graph_bench.py
# uses DCSMS_BENCH_DOMAIN + 0 .. 16
BENCH_DOMAINS = 17
pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_bench_smoke_writes_json(tmp_path):
    """The smoke run exits 0 and writes machine info plus rows with name, value and unit."""
    out = tmp_path / "results.json"
    lease = lease_domains(BENCH_DOMAINS)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               DCSMS_BENCH_DOMAIN=str(lease.first))
    try:
        subprocess.run([sys.executable, str(ROOT / "bench" / "run.py"), "--smoke", "--out",
                        str(out)], check=True, env=env, timeout=600, capture_output=True)
    finally:
        lease.release()
    data = json.loads(out.read_text())
    assert {"cpu", "cores", "python", "numpy", "date"} <= data["machine"].keys()
    assert data["smoke"] is True
    assert data["rows"]
    for row in data["rows"]:
        assert {"name", "value", "unit", "bench", "verdict"} <= row.keys()
        assert row["value"] is None or isinstance(row["value"], (int, float))
    assert {r["bench"] for r in data["rows"]} >= {"engine", "bags"}
    # the same results written into a README's bench block, replacing only that block
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- bench table: begin -->\nold\n<!-- bench table: end -->\nrest\n")
    subprocess.run([sys.executable, str(ROOT / "bench" / "run.py"), "--out", str(out),
                    "--readme", str(readme)], check=True, env=env, timeout=60,
                   capture_output=True)
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("rest\n") and "\nold\n" not in text
    assert all(f"| {r['name']} |" in text for r in data["rows"])
