"""Soak: real-time graph with a recorder; bounded memory, no lost message, no stall."""

from __future__ import annotations

import itertools
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from rel_harness import Graph, Probe, assert_clean, report
from test_record_signal import _read

from dcsms_ros.cli.record import recorder_command
from dcsms_ros.core import topics
from dcsms_ros.core.modes import Mode

#: Default (make test) and full (--soak) durations, s; DCSMS_SOAK_S overrides both.
SHORT_S, FULL_S = 25.0, 600.0
#: RSS is compared from this long after the start (imports, DDS discovery, first buffers).
WARMUP_S = 8.0


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS for {pid}")


# Multi-process timing on a shared 2-core machine: a scheduling hiccup can miss a bound
# once; two reruns keep CI meaningful (every attempt must fail for a red run).
@pytest.mark.flaky(reruns=2, reruns_delay=2)
def test_soak_realtime_with_recording(request, ctx, cfg, tmp_path):
    """Real time + recording: RSS growth < 10 %, recorder lost nothing, sim time never stalls."""
    duration = float(os.environ.get("DCSMS_SOAK_S") or
                     (FULL_S if request.config.getoption("--soak", default=False) else SHORT_S))
    bodies = topics.body_names(cfg.plant.num_stages)
    # ground and top-stage velocities at 2 kHz (the transmissibility the analysis computes) and
    # the applied forces, plus mode and diagnostics: 6k msg/s. The full set (~23k msg/s) is
    # more than a shared 2-core box records without drops while it also runs the graph
    recorded = [topics.velocity_topic(bodies[0]), topics.velocity_topic(bodies[-1]),
                topics.ACTUATORS_APPLIED, topics.MODE, topics.DIAGNOSTICS]
    bag = tmp_path / "soak"
    # reader history of 10 s per topic: the recorder may stall for seconds on a shared box
    rec = subprocess.Popen([*recorder_command(bag, recorded), "--queue-depth", "20000"],
                           stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    # the probe must not read applied: the plant would start once it did, before the
    # recorder's reader of it existed (its first 38-864 samples were missing from the bag)
    probe = Probe(ctx, applied=False)
    graph = Graph(cfg, tmp_path, mode=Mode.DFBC_FFC, extra={"plant_simulator": {
        "wait_for_subscribers": recorded[:-2]}})
    pids = {**{n: graph.pid(n) for n in graph.kids}, "recorder": rec.pid}
    progress: list[tuple[float, float]] = []
    try:
        probe.wait(lambda: float(probe.value("plant_simulator", "sim_time_s", "0")) > 0.5,
                   120.0, "plant stepping")
        t0 = time.monotonic()
        rss0: dict[str, int] = {}
        while time.monotonic() - t0 < duration:
            time.sleep(1.0)
            progress.append((time.monotonic() - t0,
                             float(probe.value("plant_simulator", "sim_time_s"))))
            if not rss0 and time.monotonic() - t0 >= min(WARMUP_S, duration / 3):
                rss0 = {n: _rss_kb(p) for n, p in pids.items()}
            assert all(k.proc.poll() is None for k in graph.kids.values()), "a node died"
        rss1 = {n: _rss_kb(p) for n, p in pids.items()}
        plant = dict(probe.diag["plant_simulator"])
    finally:
        codes = graph.stop()
        rec.send_signal(signal.SIGINT)
        _, rec_err = rec.communicate(timeout=120)
        probe.close()
    counts, stamps, final, sim_times = _read(bag)
    k = int(final["plant_simulator"]["sample"])
    dec = final["sensor_decoupling"]
    expect = {topics.ACTUATORS_APPLIED: k}
    # real time: the decoupling reads every sample and answers the newest of each wake-up
    expect.update({t: int(dec["published"]) for t in recorded[:2]})
    lost = {t: expect[t] - counts[t] for t in expect}
    applied_gaps = k - len(stamps[topics.ACTUATORS_APPLIED])
    growth = {n: (rss1[n] - rss0[n]) / rss0[n] for n in rss0}
    # the plant's own 1 Hz reports (steady clock), as recorded: each must show progress
    # from the last report before stepping began (the plant reports sim time 0 while it waits
    # for the recorder's readers); the last report may be the final one, taken at the stop
    first = next((i for i, t in enumerate(sim_times) if t > 0.0), len(sim_times))
    steps = [b - a for a, b in itertools.pairwise(sim_times[max(first - 1, 0):])][:-1]
    wall = progress[-1][0] - progress[0][0]
    sim_rate = (progress[-1][1] - progress[0][1]) / wall
    worst = max(growth, key=lambda n: growth[n])
    row = "9" if duration == SHORT_S else f"9-{duration:g}s"  # the long soak keeps its own row
    report(row, f"soak {duration:g} s real time, DFBC+FFC, recording {len(recorded)} topics",
           "RSS bounded, recorder lost nothing, sim time advanced every second",
           f"max RSS growth {growth[worst]:+.1%} ({worst}); {sum(counts.values())} msgs, "
           f"{sum(lost.values())} lost, {applied_gaps} gaps; sim {sim_rate:.2f}x real time, "
           f"{plant['achieved_rate_hz']} Hz, overruns {plant['overruns']}",
           duration_s=duration, rss_growth=growth, lost=lost, gaps=applied_gaps,
           sim_rate=sim_rate, min_sim_step_s=min(steps), counts=dict(counts))
    assert rec.returncode == 0, rec_err
    assert all(c == 0 for c in codes.values()), codes
    assert all(g < 0.10 for g in growth.values()), growth
    assert all(v == 0 for v in lost.values()), lost
    assert applied_gaps == 0
    assert len(sim_times) >= 0.7 * duration, f"{len(sim_times)} plant reports in {duration} s"
    assert min(steps) > 0.0, f"sim time stalled: {steps}"  # advanced in every 1 s report
    assert_clean(graph.logs())
