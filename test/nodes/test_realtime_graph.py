"""Real-time graph through the CLI: switch with `dcsms mode`, report the rate, stop with SIGINT."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from node_helpers import executor_for
from test_composed import _read

from dcsms_ros import cdr
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.ros import qos

DCSMS = [sys.executable, "-m", "dcsms_ros.cli"]


def test_realtime_graph_switches_mode_and_stops_cleanly(ctx, tmp_path):
    """`dcsms up --realtime` steps, `dcsms mode DFBC+FFC` switches it, SIGINT exits 0."""
    probe = rclpy.create_node("rate_probe", context=ctx)
    plant: dict[str, str] = {}

    def on_diag(msg: DiagnosticArray) -> None:
        for st in msg.status:
            if st.name == topics.DEFAULT.status("plant_simulator"):
                plant.update({kv.key: kv.value for kv in st.values})

    probe.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, on_diag, qos.status())
    ex = executor_for(ctx, probe)
    logs = tmp_path / "logs"
    up = subprocess.Popen([*DCSMS, "up", "--realtime", "--log-dir", str(logs)],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 90.0
        while int(plant.get("sample", "0")) == 0 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.1)
        assert int(plant.get("sample", "0")) > 0, "the plant never stepped"
        sw = subprocess.run([*DCSMS, "mode", "DFBC+FFC", "--timeout", "20"], check=False,
                            capture_output=True, text=True, timeout=60)
        assert sw.returncode == 0, sw.stdout + sw.stderr
        assert "mode DFBC+FFC" in sw.stdout
        now = subprocess.run([*DCSMS, "mode", "--timeout", "20"], capture_output=True, text=True,
                             check=False,
                             timeout=60)
        lines = now.stdout.splitlines()
        assert lines[0] == "DFBC+FFC", now.stdout + now.stderr
        # the supervisor's state: the user's switch engaged DFBC+FFC
        assert lines[1].startswith("supervisor: ENGAGED DFBC+FFC at "), now.stdout
        t_end = time.monotonic() + 3.0
        while time.monotonic() < t_end:
            ex.spin_once(timeout_sec=0.1)
    finally:
        up.send_signal(signal.SIGINT)
        out = up.communicate(timeout=60)[0]
    assert up.returncode == 0, out
    texts = [out] + [p.read_text() for p in logs.glob("*.log")]
    assert not any("Traceback" in t for t in texts), out
    # the summary of a run stopped by a signal: the plant's last report, as a line and as JSON
    summary = json.loads((logs / "summary.json").read_text())
    assert summary["samples"] >= int(plant["sample"]) > 0, (summary, plant)
    assert f"dcsms up: summary: samples {summary['samples']}, late {summary['late']} " in out
    assert summary["recorded"] is None and out.rstrip().endswith("dcsms up: stopped"), out
    print(f"\nreal time: achieved {plant.get('achieved_rate_hz')} Hz of {plant.get('rate_hz')} "
          f"Hz at t={plant.get('sim_time_s')} s; stale events {plant.get('stale_events')}, "
          f"overruns {plant.get('overruns')}")
    ex.shutdown()


def test_mode_cli_rejects_unknown_name_and_reports_missing_graph(domain):
    """An unknown mode exits 2 listing the valid ones; no graph -> a clear error, status 1."""
    bad = subprocess.run([*DCSMS, "mode", "SKYHOOK"], capture_output=True, text=True, timeout=60,
                         check=False)
    assert bad.returncode == 2
    assert "DFBC+FFC" in bad.stderr and "Traceback" not in bad.stderr
    gone = subprocess.run([*DCSMS, "mode", "fbc", "--timeout", "0.5"], capture_output=True,
                          check=False,
                          text=True, timeout=60)
    assert gone.returncode == 1
    assert "not available" in gone.stderr and "Traceback" not in gone.stderr


def _delayed_from_bag(got: dict[str, list[tuple[int, bytes]]], rate: float,
                      timeout_s: float, before_s: float = 0.0) -> int:
    """Samples x controllers at which the newest force published before the sample answers
    a sample older than the previous one, without being older than ``timeout_s``."""
    raw = cdr.decode_batch(cdr.JOINT_STATE, [m for _, m in got[topics.SENSORS_RAW]])
    steps = np.round(raw.stamp_ns * rate / 1e9).astype(int)
    t_raw = np.array([t for t, _ in got[topics.SENSORS_RAW]], dtype=np.int64)
    at = dict(zip(steps.tolist(), t_raw.tolist(), strict=True))
    n = 0
    for c in ("fb_stage1", "fb_stage2", "ff_stage1"):
        msgs = got[topics.force_topic(c)]
        b = cdr.decode_batch(cdr.WRENCH_STAMPED, [m for _, m in msgs])
        k = np.round(b.stamp_ns * rate / 1e9).astype(int)
        keep = ~_watchdog_zeros(k, b.fields["wrench"])
        k, t = k[keep], np.array([t for t, _ in msgs], dtype=np.int64)[keep]
        newest = np.searchsorted(t, t_raw - int(before_s * 1e9)) - 1  # in sample order
        for s, t_s, i in zip(steps[1:], t_raw[1:], newest[1:], strict=True):
            if i < 0:
                continue  # nothing answered yet
            j = int(k[i])
            if t_s - at.get(j, t_s) > timeout_s * 1e9:
                continue  # stale, not delayed
            n += int(j < s - 1)
    return n


def _watchdog_zeros(k: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """Mask of a force stream's watchdog zeros: a controller whose input stayed away for
    ``control.input_timeout_s`` publishes zero force stamped with the sample time it reckons
    the plant has reached, and the late inputs it answers next carry older stamps (the plant
    keeps the newest force by sample time). A CI run had one: fb_stage1, k 3574, then a zero
    at 3598, then the answers to 3597 and 3598, with 25 % of the samples late. The zeros that
    are not older than some later message are those."""
    later = np.minimum.accumulate(k[::-1])[::-1]  # the smallest stamp from each one on
    later = np.r_[later[1:], np.iinfo(k.dtype).max]
    return ~np.any(wrench, axis=1) & (k >= later)


def test_recorded_real_time_bag_starts_at_sample_zero(domain: int, cfg: SystemConfig,
                                                      tmp_path: Path) -> None:
    """`dcsms up --realtime --record`, one process per node: each node process records the
    per-sample topics it publishes (no recorder process subscribes to them), the recorder
    process the rest, and `dcsms up` merges them into the bag. So the bag holds the run from
    sample 0 and every per-sample message published (before: the recorder process kept 35-51 %
    on this machine, and once subscribed 2-3 s after the plant started)."""
    bag, logs = tmp_path / "bag", tmp_path / "logs"
    proc = subprocess.run([*DCSMS, "up", "--realtime", "--mode", "DFBC+FFC", "--duration", "2",
                           "--record", str(bag), "--log-dir", str(logs)],
                          capture_output=True, text=True, timeout=180, check=False,
                          env={**os.environ, "ROS_DOMAIN_ID": str(domain)})
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Traceback" not in out, out[-3000:]
    assert "starting without" not in logs.joinpath("plant_simulator.log").read_text(), out
    assert not tmp_path.joinpath("bag.parts").exists(), "the parts stay only if a merge failed"
    graph = yaml.safe_load(logs.joinpath("graph.yaml").read_text())
    waited = graph["shared"]["wait_for_subscribers"]
    assert topics.SENSORS_RAW not in waited and topics.MODE in waited, waited
    assert f"recording {topics.SENSORS_RAW}" not in logs.joinpath("recorder.log").read_text()
    summary = json.loads(logs.joinpath("summary.json").read_text())
    assert summary["recorded"] == summary["published"] > 0, summary
    assert 0 <= summary["woke_late"] <= summary["late"], summary
    got = _read(bag)
    meta = yaml.safe_load(bag.joinpath("metadata.yaml").read_text())["rosbag2_bagfile_information"]
    published = json.loads(meta["custom_data"]["dcsms_ros.published"])
    rate = cfg.plant.rate_hz
    streams = [(topics.SENSORS_RAW, cdr.JOINT_STATE), (topics.ACTUATORS_APPLIED, cdr.JOINT_STATE),
               *[(topics.truth_topic(b), cdr.TWIST_STAMPED) for b in ("ground", "stage1")],
               *[(topics.velocity_topic(b), cdr.TWIST_STAMPED) for b in ("ground", "stage2")],
               *[(topics.force_topic(c), cdr.WRENCH_STAMPED) for c in ("fb_stage1",
                                                                        "ff_stage1")]]
    for topic, msgtype in streams:
        batch = cdr.decode_batch(msgtype, [m for _, m in got[topic]])
        stamps = batch.stamp_ns
        assert len(stamps) == published[topic], (topic, len(stamps), published[topic])
        k = np.round(stamps * rate / 1e9).astype(int)
        if msgtype == cdr.WRENCH_STAMPED:
            ahead = _watchdog_zeros(k, batch.fields["wrench"])
            if ahead.any():  # only from a controller that said so
                log = logs.joinpath(f"{topic.rsplit('/', 1)[1]}.log").read_text()
                assert "zero force" in log, (topic, int(ahead.sum()))
            k = k[~ahead]
        assert np.all(np.diff(k) > 0), topic  # each sample once, in order
        assert k.max() >= int(1.9 * rate) - 1, (topic, k.max())
        if topic in (topics.SENSORS_RAW, topics.truth_topic("stage1")):
            assert k.min() == 0 and len(k) == k.max() + 1, (topic, k.min(), len(k))
    # the forces applied one sample late or more (summary "delayed"), bounded from the bag's
    # publication times (each part logs a message at its publication, on one clock): at step s
    # the plant holds the newest answer it drained just before it published sample s. An
    # answer published after sample s was not there (the lower bound); one published 0.25 ms
    # (half a period) before it was (the upper bound: the drain runs ~50-100 us before the
    # publication here, 3 runs: 1,443 / 1,513 / 1,988 delayed, bounds 1,253-1,720,
    # 1,226-1,819, 1,744-2,108 at 0.1 ms)
    lo = _delayed_from_bag(got, rate, cfg.control.input_timeout_s)
    hi = _delayed_from_bag(got, rate, cfg.control.input_timeout_s, before_s=0.5 / rate)
    assert lo - 12 <= summary["delayed"] <= hi, (lo, summary["delayed"], hi)
