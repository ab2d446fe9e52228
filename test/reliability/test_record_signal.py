"""SIGINT/SIGTERM/SIGHUP to `dcsms up --lockstep --record`: exit 0, bag complete to the last
message."""

from __future__ import annotations

import importlib
import signal
import subprocess
import time
from collections import Counter, defaultdict
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message
from rel_harness import DCSMS, Probe, assert_clean, report
from rosbags.rosbag2 import Reader

from dcsms_ros.core import topics
from dcsms_ros.core.modes import controller_ids


def get_message(msgtype: str) -> type:
    """``pkg/msg/Name`` -> the rclpy message class."""
    pkg, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.msg"), name)


def _read(bag: Path) -> tuple[Counter, dict[str, set[int]], dict[str, dict[str, str]],
                             list[float]]:
    """Per-topic counts, distinct stamps (ns) of stamped topics, last status of every node,
    and the plant's simulated time in each of its reports."""
    counts: Counter = Counter()
    stamps: dict[str, set[int]] = defaultdict(set)
    final: dict[str, dict[str, str]] = {}
    sim_times: list[float] = []
    with Reader(bag) as reader:
        types = {c.topic: get_message(c.msgtype) for c in reader.connections}
        for conn, _, raw in reader.messages():
            counts[conn.topic] += 1
            msg = deserialize_message(bytes(raw), types[conn.topic])
            if isinstance(msg, DiagnosticArray):
                for st in msg.status:
                    name = topics.DEFAULT.local_status(st.name)
                    if name is None:
                        continue
                    final[name] = {kv.key: kv.value for kv in st.values}
                    if name == "plant_simulator":
                        sim_times.append(float(final[name]["sim_time_s"]))
            elif hasattr(msg, "header"):
                stamps[conn.topic].add(msg.header.stamp.sec * 1_000_000_000
                                       + msg.header.stamp.nanosec)
    return counts, stamps, final, sim_times


def _recording_up(probe: Probe, bag: Path, logs: Path) -> subprocess.Popen[str]:
    """`dcsms up --lockstep --record BAG` (one process per node), once it recorded 1500
    samples; killed if it fails before."""
    up = subprocess.Popen([*DCSMS, "up", "--lockstep", "--mode", "DFBC+FFC", "--record",
                           str(bag), "--log-dir", str(logs)], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True)
    try:
        probe.wait(lambda: int(probe.value("plant_simulator", "sample", "0")) > 1500, 120.0,
                   "lockstep graph recorded for a while")
    except BaseException:
        up.kill()
        up.wait()
        probe.close()
        raise
    return up


# Multi-process timing on a shared 2-core machine: a scheduling hiccup can miss a bound
# once; two reruns keep CI meaningful (every attempt must fail for a red run).
@pytest.mark.flaky(reruns=2, reruns_delay=2)
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP],
                         ids=["SIGINT", "SIGTERM", "SIGHUP"])
def test_signal_to_recording_graph_leaves_complete_bag(sig, ctx, cfg, tmp_path):
    """Signal mid-run: exit 0, no traceback, bag counts equal the publishers' final counters."""
    probe = Probe(ctx)
    bag, logs = tmp_path / "bag", tmp_path / "logs"
    up = _recording_up(probe, bag, logs)
    try:
        t_sig = time.monotonic()
        up.send_signal(sig)
        out, err = up.communicate(timeout=60)
        stop_s = time.monotonic() - t_sig
    finally:
        if up.poll() is None:
            up.kill()
        probe.close()
    counts, stamps, final, _ = _read(bag)
    n = cfg.plant.num_stages
    plant, dec = final["plant_simulator"], final["sensor_decoupling"]
    k = int(plant["sample"])
    expect = {topics.ACTUATORS_APPLIED: k,
              topics.SENSORS_RAW: len(stamps[topics.SENSORS_RAW]) + int(plant["retransmits"])}
    expect.update({topics.truth_topic(b): len(stamps[topics.SENSORS_RAW])
                   for b in topics.body_names(n)})
    expect.update({topics.velocity_topic(b): int(dec["samples"]) + int(dec["repeats"])
                   for b in topics.body_names(n)})
    expect.update({topics.force_topic(c): int(final[c]["samples"]) + int(final[c]["repeats"])
                   for c in controller_ids(n)})
    got = {t: counts[t] for t in expect}
    name = signal.Signals(sig).name
    report(f"4-{name}", f"{name} to `dcsms up --lockstep --record` after {k} samples",
           f"exit {up.returncode} in {stop_s:.1f} s, no traceback, bag counts = published",
           f"{sum(got.values())} stream messages, {sum(g != expect[t] for t, g in got.items())}"
           f" topics off; {len(counts)} topics", counts=dict(counts), expected=expect)
    assert up.returncode == 0, err
    assert "Traceback" not in err + out, err
    assert_clean("\n".join(p.read_text() for p in logs.glob("*.log")))
    assert got == expect, {t: (got[t], expect[t]) for t in got if got[t] != expect[t]}
    # lockstep: every sample from 0 on, no gap (raw k+1 may be out, its answer cut by the stop)
    raw = sorted(stamps[topics.SENSORS_RAW])
    assert raw[0] == 0 and len(raw) in (k, k + 1), (raw[:3], len(raw), k)
    assert counts[topics.MODE] >= 1 and counts.get("/dcsms/config", 0) >= 1


def test_a_killed_up_leaves_parts_that_recover_merges(ctx, cfg, tmp_path):
    """SIGKILL to `dcsms up --lockstep --record` (no clean-up of its own): its node and recorder
    processes still close their parts (SIGTERM at their parent's death), which stay unmerged in
    OUT.parts; `dcsms recover OUT` merges them into a bag whose streams run from sample 0 with
    no gap."""
    probe = Probe(ctx)
    bag, logs = tmp_path / "bag", tmp_path / "logs"
    up = _recording_up(probe, bag, logs)
    try:
        up.kill()
        up.wait(10)
        parts = bag.with_name("bag.parts")
        probe.wait(lambda: parts.is_dir() and len(list(parts.iterdir())) >= 2 and all(
            (p / "metadata.yaml").is_file() for p in parts.iterdir()), 30.0,
            "every part closed after its parent's death")
    finally:
        if up.poll() is None:
            up.kill()
        probe.close()
    assert not bag.exists()
    rec = subprocess.run([*DCSMS, "recover", str(bag)], capture_output=True, text=True,
                         timeout=120, check=False)
    assert rec.returncode == 0 and "not closed" not in rec.stdout, rec.stdout + rec.stderr
    counts, stamps, _, _ = _read(bag)
    period_ns = round(1e9 / cfg.plant.rate_hz)
    raw = sorted(stamps[topics.SENSORS_RAW])
    assert len(raw) > 1500 and raw == [k * period_ns for k in range(len(raw))], raw[:5]
    for b in topics.body_names(cfg.plant.num_stages):
        assert counts[topics.velocity_topic(b)] >= len(raw) - 2, counts
    assert counts[topics.MODE] >= 1 and not bag.with_name("bag.parts").exists()
    assert_clean("\n".join(p.read_text() for p in logs.glob("*.log")))
