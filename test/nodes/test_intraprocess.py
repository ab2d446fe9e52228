"""In-process delivery of the composed graph over real DDS: the in-process recorder keeps every
message (lockstep and real time), the graph stays the batch engine's bit for bit, and a
recorder in another process that joins and leaves mid-run gets every message published while
it was there (and the velocities' history) - exactly once."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_composed import _read, _series, _streams

from dcsms_ros import cdr
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig

pytestmark = pytest.mark.slow

DCSMS = [sys.executable, "-m", "dcsms_ros.cli"]
TIMEOUT_S = 400.0


def _run(args: list[str], log: Path, domain: int) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run([*DCSMS, *args], capture_output=True, text=True, timeout=TIMEOUT_S,
                          check=False, env={**os.environ, "ROS_DOMAIN_ID": str(domain)})
    log.write_text(proc.stdout + proc.stderr)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "Traceback" not in proc.stdout + proc.stderr
    return proc


def _stamps(msgs: list[tuple[int, bytes]], msgtype: str) -> np.ndarray:
    return cdr.decode_batch(msgtype, [m for _, m in msgs]).stamp_ns


def test_in_process_recorder_keeps_every_lockstep_message_bit_for_bit(
        domain: int, cfg: SystemConfig, tmp_path: Path) -> None:
    """`sim --engine graph --composed --recorder composed` (refused before: that recorder kept
    89,061 of 220,000 messages): every per-sample stream has each of the N samples, with the
    batch engine's numbers, and no sample twice except lockstep retransmissions of one stamp
    with the same bytes."""
    common = ["--mode", "dfbc_ffc", "--duration", "1.0", "--seed", "3"]
    graph, batch = tmp_path / "graph", tmp_path / "batch"
    _run(["sim", *common, "--engine", "graph", "--composed", "--recorder", "composed",
          "--out", str(graph)], tmp_path / "graph.log", domain)
    _run(["sim", *common, "--engine", "batch", "--out", str(batch)], tmp_path / "batch.log",
         domain)
    got, ref = _read(graph), _read(batch)
    n = int(round(1.0 * cfg.plant.rate_hz))
    for topic, msgtype in _streams(cfg.plant.num_stages).items():
        gs, gv = _series(got[topic], msgtype)
        bs, bv = _series(ref[topic], msgtype)
        assert gs.size == bs.size == n, (topic, gs.size)
        np.testing.assert_array_equal(gs, bs, err_msg=topic)
        np.testing.assert_array_equal(gv, bv, err_msg=topic)
        assert len(got[topic]) - n <= 2, (topic, len(got[topic]))  # sample 0's repeats


def _wait_for(path: Path, text: str, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if path.exists() and text in path.read_text(errors="replace"):
            return
        time.sleep(0.05)
    raise AssertionError(f"{text!r} not in {path} after {timeout_s} s")


def test_a_remote_recorder_joining_and_leaving_mid_run_gets_every_message_once(
        domain: int, cfg: SystemConfig, tmp_path: Path) -> None:
    """Composed lockstep, recorded in process (the reference: every sample), and `dcsms record`
    in another process started after the plant steps and stopped before it ends. That
    recorder's raw samples and forces are one unbroken run of stamps, each once, byte for byte
    the in-process bag's; its velocities (transient local) start with the history held while
    no remote reader was there. The run goes on and ends by itself after it left."""
    seconds = 90.0  # ~20-40 s of wall time: the late recorder needs a few to start
    n = int(round(seconds * cfg.plant.rate_hz))
    full, late = tmp_path / "full", tmp_path / "late"
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    up_log = tmp_path / "up.log"
    with up_log.open("w") as out:
        up = subprocess.Popen([*DCSMS, "up", "--composed", "--lockstep", "--mode", "DFBC+FFC",
                               "--duration", str(seconds), "--record", str(full),
                               "--recorder", "composed", "--log-dir", str(tmp_path / "logs")],
                              stdout=out, stderr=subprocess.STDOUT, env=env, text=True)
    try:
        _wait_for(tmp_path / "logs" / "graph.log", "graph connected", 60.0)
        rec_log = tmp_path / "record.log"
        with rec_log.open("w") as rout:
            rec = subprocess.Popen([*DCSMS, "record", str(late), "--queue-depth", "25000"],
                                   stdout=rout, stderr=subprocess.STDOUT, env=env, text=True)
        _wait_for(rec_log, f"recording {topics.SENSORS_RAW}", 60.0)
        time.sleep(6.0)  # the join replays up to 25,000 held samples per durable topic first
        rec.send_signal(signal.SIGINT)
        assert rec.wait(60.0) == 0, rec_log.read_text()[-2000:]
        assert up.wait(TIMEOUT_S) == 0, up_log.read_text()[-3000:]
    finally:
        if up.poll() is None:  # `dcsms up` stops its composed process on SIGINT
            up.send_signal(signal.SIGINT)
            try:
                up.wait(30.0)
            except subprocess.TimeoutExpired:
                up.kill()
    ref, got = _read(full), _read(late)
    raw = topics.SENSORS_RAW
    for topic, msgtype in _streams(cfg.plant.num_stages).items():
        stamps, _ = _series(ref[topic], msgtype)
        assert stamps.size == n, (topic, stamps.size)  # the in-process recorder: all of them
    first = None
    for topic in (raw, *(topics.force_topic(c) for c in ("fb_stage1", "fb_stage2",
                                                          "ff_stage1"))):
        msgtype = cdr.JOINT_STATE if topic == raw else cdr.WRENCH_STAMPED
        s = _stamps(got[topic], msgtype)
        k = np.round(s * cfg.plant.rate_hz / 1e9).astype(int)
        assert k[0] > 0 and k[-1] < n - 1, (topic, k[0], k[-1])  # joined and left mid-run
        np.testing.assert_array_equal(k, np.arange(k[0], k[-1] + 1), err_msg=topic)
        byref = {int(np.round(t * cfg.plant.rate_hz / 1e9)): m
                 for t, m in zip(_stamps(ref[topic], msgtype), (m for _, m in ref[topic]),
                                 strict=True)}
        assert all(byref[int(i)] == m for i, (_, m) in zip(k, got[topic], strict=True)), topic
        if topic == raw:
            first = int(k[0])
    assert first is not None
    vel = topics.velocity_topic("stage1")
    s = _stamps(got[vel], cdr.TWIST_STAMPED)
    k = np.round(s * cfg.plant.rate_hz / 1e9).astype(int)
    np.testing.assert_array_equal(k, np.arange(k[0], k[-1] + 1))
    assert k[0] < first  # the history held in the process reached the late joiner first


def test_in_process_recorder_keeps_every_real_time_sample(domain: int, cfg: SystemConfig,
                                                          tmp_path: Path) -> None:
    """Composed real time, recorder in the process: every message published is in the bag, once
    and in order - the plant's samples (raw, truth) N of N, and for every topic the writer's
    sequence numbers without a gap (the recorder's report). What a real-time reader skipped for
    a newer sample (keep-last 1, a late wake-up on this shared machine) was never published."""
    seconds = 3.0
    n = int(round(seconds * cfg.plant.rate_hz))
    bag, logs = tmp_path / "bag", tmp_path / "logs"
    _run(["up", "--composed", "--realtime", "--mode", "DFBC+FFC", "--duration", str(seconds),
          "--record", str(bag), "--recorder", "composed", "--log-dir", str(logs)],
         tmp_path / "up.log", domain)
    got = _read(bag)
    for topic, msgtype in _streams(cfg.plant.num_stages).items():
        s = _stamps(got[topic], msgtype)
        k = np.round(s * cfg.plant.rate_hz / 1e9).astype(int)
        if topic.startswith(topics.NAMESPACE + "/force/"):
            # a stale controller's zero force is stamped ahead (controller_node.py), so stamps
            # may step back when its input returns: no message twice is the check here
            assert len({m for _, m in got[topic]}) == k.size, topic
        else:
            assert np.all(np.diff(k) > 0), topic  # once each, in order
        if topic == topics.SENSORS_RAW or topic.startswith(topics.NAMESPACE + "/truth/"):
            np.testing.assert_array_equal(k, np.arange(n), err_msg=topic)
    report = logs.joinpath("graph.log").read_text()
    rows = {line.split()[0]: line.split() for line in report.splitlines()
            if line.startswith(topics.NAMESPACE + "/") and len(line.split()) >= 4}
    assert set(_streams(cfg.plant.num_stages)) <= set(rows), sorted(rows)
    for topic, row in rows.items():
        assert row[3] == "0(0)", (topic, row)  # seq gaps (missing): none
        assert int(row[1]) == len(got.get(topic, [])), (topic, row)


def _container_pid(domain: int) -> int | None:
    """The composed process of this test's domain (its command line names the container)."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes()
            env = (d / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"dcsms_ros.nodes.container" in cmd and f"ROS_DOMAIN_ID={domain}".encode() in env:
            return int(d.name)
    return None


def test_a_killed_composed_process_leaves_a_closed_bag(domain: int, cfg: SystemConfig,
                                                       tmp_path: Path) -> None:
    """The composed process killed mid-run (SIGKILL: no drain, no close): its bag writer
    process closes the bag with what it had received, renamed into place and readable, each
    plant sample once and in order from the first, and `dcsms up` waits for it. Written in the
    killed process, as before the bag writer process, the bag was lost with it."""
    bag, logs = tmp_path / "bag", tmp_path / "logs"
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
    up_log = tmp_path / "up.log"
    with up_log.open("w") as out:
        up = subprocess.Popen([*DCSMS, "up", "--composed", "--lockstep", "--mode", "DFBC+FFC",
                               "--duration", "600", "--record", str(bag), "--log-dir", str(logs)],
                              stdout=out, stderr=subprocess.STDOUT, env=env, text=True)
    try:
        _wait_for(logs / "graph.log", "graph connected", 60.0)
        time.sleep(3.0)
        pid = _container_pid(domain)
        assert pid is not None
        os.kill(pid, signal.SIGKILL)
        assert up.wait(60.0) != 0  # a process died: said, not hidden
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
    # `dcsms up` waited for the orphaned bag writer process: the bag is closed when it returns
    assert (bag / "metadata.yaml").exists()
    # named by its command line or, once it has exited, by the name it gave itself
    assert re.search(r"(dcsms_ros\.analysis\.)?bagserve \(pid \d+\), left behind",
                     up_log.read_text())
    got = _read(bag)
    raw = got[topics.SENSORS_RAW]
    k = np.round(_stamps(raw, cdr.JOINT_STATE) * cfg.plant.rate_hz / 1e9).astype(int)
    once = np.unique(k)
    assert once.size > 1000  # seconds of lockstep samples (thousands a second)
    np.testing.assert_array_equal(once, np.arange(once.size))
    assert k.size - once.size <= 2 and np.all(np.diff(k) >= 0)  # sample 0's repeats only
    assert "ended without closing" in logs.joinpath("graph.log").read_text()
