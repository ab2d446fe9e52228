"""Bag analysis: chunk reader and ``dcsms analyze`` next to a plain rosbags deserialize loop."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test" / "analysis"))

# VmHWM, not ru_maxrss: Linux carries the parent's peak RSS across fork/exec into ru_maxrss.
_PEAK = """
import sys
from dcsms_ros.analysis.report import analyze
analyze([sys.argv[1]]) if sys.argv[1] != '-' else None
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
print(int(hwm.split()[1]) / 1024.0)
"""


def _bag(tmp: Path, name: str, seconds_per_mode: float) -> tuple[Path, int]:
    """Synthetic 2 kHz bag, 4 modes x ``seconds_per_mode``, 4 data topics; (path, messages)."""
    from synth_bag import write_bag

    path = write_bag(tmp / name, fs=2000.0, seconds=seconds_per_mode)
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        return path, int(r.message_count)


def _rosbags_loop(path: Path) -> float:
    """Messages per second of a per-message rosbags ``deserialize_cdr`` loop (the baseline)."""
    from rosbags.rosbag2 import Reader

    from dcsms_ros.analysis.cdr import typestore

    ts = typestore()
    t0 = time.perf_counter()
    n = 0
    with Reader(path) as r:
        for conn, _, raw in r.messages():
            ts.deserialize_cdr(raw, conn.msgtype)
            n += 1
    return n / (time.perf_counter() - t0)


def _peak_mb(bag: Path | str) -> float:
    out = subprocess.run([sys.executable, "-c", _PEAK, str(bag)], check=True,
                         capture_output=True, text=True, timeout=1200)
    return float(out.stdout.strip().splitlines()[-1])


def run(smoke: bool, tmp: Path) -> list[dict[str, Any]]:
    """Rows: read_bag and analyze msg/s vs the rosbags loop; peak memory per recorded minute."""
    from dcsms_ros.analysis.reader import read_bag
    from dcsms_ros.analysis.report import analyze

    small, _ = _bag(tmp, "warm", 2.0)
    analyze([small])  # imports and first-call costs out of the timed runs
    bag, n = _bag(tmp, "big", 1.25 if smoke else 31.25)  # 20 k or 1 M messages
    base = _rosbags_loop(bag)
    t0 = time.perf_counter()
    read_bag(bag)
    read = n / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    analyze([bag])
    full = n / (time.perf_counter() - t0)
    rows = [
        {"name": f"bags: read_bag, {n} msgs", "value": read, "unit": "msg/s",
         "baseline_name": "rosbags deserialize_cdr loop", "baseline": base},
        {"name": f"bags: analyze() in process, {n} msgs", "value": full, "unit": "msg/s",
         "baseline_name": "rosbags deserialize_cdr loop", "baseline": base,
         "target": 1e6, "target_ratio": 5.0},
    ]
    minutes = (0.1, 0.2) if smoke else (2.0, 10.0)
    peaks = []
    for m in minutes:
        b, nm = _bag(tmp, f"mem{m:g}", m * 60.0 / 4.0)
        peaks.append((m, nm, _peak_mb(b)))
    base_mb = _peak_mb("-")
    (m0, _, p0), (m1, n1, p1) = peaks
    slope = (p1 - p0) / (m1 - m0)
    hour = p1 + slope * (60.0 - m1)
    rows.append({"name": "bags: analyze peak RSS, 1 h at 2 kHz (linear from "
                 f"{m0:g} and {m1:g} min)", "value": hour, "unit": "MB",
                 "baseline_name": "python + imports only", "baseline": base_mb,
                 "target_max": 1024.0,
                 "note": f"measured {p0:.0f} MB at {m0:g} min, {p1:.0f} MB at {m1:g} min "
                         f"({slope:.1f} MB/min)"})
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "dcsms_ros.cli", "analyze", str(b)], check=True,
                   capture_output=True, timeout=1200)
    cli = n1 / (time.perf_counter() - t0)
    rows.append({"name": f"bags: `dcsms analyze` CLI end to end, {n1} msgs", "value": cli,
                 "unit": "msg/s", "baseline_name": "rosbags deserialize_cdr loop",
                 "baseline": base, "target": 1e6, "target_ratio": 5.0,
                 "note": "includes interpreter start and imports"})
    return rows
