"""`dcsms demo` through the graph, interrupted: it says so and does not analyse a partial run."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DCSMS = [sys.executable, "-m", "dcsms_ros.cli"]


def test_an_interrupted_demo_exits_130_without_a_table(domain, tmp_path):
    """SIGINT once the graph steps: the demo stops the graph, keeps the bag, prints one line
    on stderr, exits 130 and writes no report (a partial schedule analysed as a whole printed
    "NOT reproduced" for modes that never ran)."""
    out = tmp_path / "demo"
    demo = subprocess.Popen([*DCSMS, "demo", "--composed", "--config",
                             str(ROOT / "config" / "table1.yaml"), "--segment", "5",
                             "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120.0
        # the status line (every ~5 s) shows the graph stepping
        while time.monotonic() < deadline and not any(
                (out / "logs").glob("graph.log")):
            time.sleep(0.2)
        time.sleep(6.0)
    finally:
        demo.send_signal(signal.SIGINT)
        stdout, stderr = demo.communicate(timeout=120)
    assert demo.returncode == 130, stdout + stderr
    assert "interrupted before the schedule ended" in stderr, stderr
    assert "Traceback" not in stdout + stderr
    assert (out / "bag").is_dir() and not (out / "report.md").exists()
    assert "order in" not in stdout and "ordering in" not in stdout
