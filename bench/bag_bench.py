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
    from synth_bag import write_bag  # type: ignore[import-not-found]  # test/analysis, above

    path = write_bag(tmp / name, fs=2000.0, seconds=seconds_per_mode)
    from rosbags.rosbag2 import Reader

    with Reader(path) as r:
        return path, int(r.message_count)


def long_bag(path: Path, minutes: float, fs: float = 2000.0) -> tuple[Path, int]:
    """A ``minutes``-long single-mode (Passive) 1-DOF bag as the graph records it: ground,
    stage-1 and stage-2 TwistStamped, applied forces, mode and configuration at ``fs``.

    Written one second at a time, topics interleaved per second, with a 3.8 Hz resonance
    filtered from white ground noise (filter state carried), so memory stays flat whatever the
    length; returns (path, messages)."""
    import numpy as np
    from scipy import signal

    from dcsms_ros import cdr
    from dcsms_ros.analysis.bagio import LATCHED_QOS, open_bag
    from dcsms_ros.analysis.reader import CONFIG_TOPIC, config_to_yaml
    from dcsms_ros.core.config import load_config

    rng = np.random.default_rng(7)
    b, a = signal.iirpeak(3.77, 5.0, fs=fs)
    zi = [np.zeros(2), np.zeros(2)]
    step = int(round(1e9 / fs))
    k = int(round(fs))
    n = 0
    with open_bag(path) as w:
        w.add_topic("/dcsms/mode", "std_msgs/msg/String", LATCHED_QOS)
        w.add_topic(CONFIG_TOPIC, "std_msgs/msg/String", LATCHED_QOS)
        t0 = 1_000_000_000
        w.write(CONFIG_TOPIC, t0, cdr.encode_string(config_to_yaml(load_config())))
        w.write("/dcsms/mode", t0, cdr.encode_string("Passive"))
        for body in ("ground", "stage1", "stage2"):
            w.add_topic(f"/dcsms/velocity/{body}", cdr.TWIST_STAMPED)
        w.add_topic("/dcsms/actuators/applied", cdr.JOINT_STATE)
        n += 2
        for sec in range(int(round(minutes * 60.0))):
            t = t0 + (sec * k + np.arange(k, dtype=np.int64)) * step
            vb = 5e-6 * rng.standard_normal(k)
            v1, zi[0] = signal.lfilter(b, a, vb, zi=zi[0])
            v2, zi[1] = signal.lfilter(b, a, v1, zi=zi[1])
            for body, vel in (("ground", vb), ("stage1", vb + v1), ("stage2", vb + v2)):
                tw = np.zeros((k, 6))
                tw[:, 2] = vel
                w.write_many(f"/dcsms/velocity/{body}", t,
                             cdr.encode_stamped(cdr.TWIST_STAMPED, t, body, tw))
            w.write_many("/dcsms/actuators/applied", t,
                         cdr.encode_joint_state(t, "", ["stage1", "stage2"],
                                                effort=np.zeros((k, 2))))
            n += 4 * k
    return path, n


def _rosbags_loop(path: Path) -> float:
    """Messages per second of a per-message rosbags ``deserialize_cdr`` loop (the baseline)."""
    from rosbags.rosbag2 import Reader

    from dcsms_ros.cdr import typestore

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
    minutes = 0.2 if smoke else 60.0
    b, n1 = long_bag(tmp / f"long{minutes:g}", minutes)
    peak = _peak_mb(b)
    base_mb = _peak_mb("-")
    rows.append({"name": f"bags: analyze peak RSS (VmHWM), {minutes:g} min at 2 kHz, one mode, "
                 f"{n1} msgs", "value": peak, "unit": "MB",
                 "baseline_name": "python + imports only", "baseline": base_mb,
                 "target_max": 1024.0 if not smoke else None,
                 "note": "measured on a recording of that length (one Passive segment: the "
                         "worst case, the whole hour is one Welch record)"})
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "dcsms_ros.cli", "analyze", str(b)], check=True,
                   capture_output=True, timeout=1200)
    cli = n1 / (time.perf_counter() - t0)
    rows.append({"name": f"bags: `dcsms analyze` CLI end to end, {n1} msgs", "value": cli,
                 "unit": "msg/s", "baseline_name": "rosbags deserialize_cdr loop",
                 "baseline": base, "target": 1e6, "target_ratio": 5.0,
                 "note": "includes interpreter start and imports"})
    return rows
