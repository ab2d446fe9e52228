"""kill -9 of sensor_decoupling in a real-time graph: every controller falls to zero force."""

from __future__ import annotations

import numpy as np
import pytest
from rel_harness import Graph, Jitter, Probe, assert_clean, report

from dcsms_ros.core.modes import Mode, controller_ids

#: Scheduling allowance on top of the timeout and the watchdog period (a loaded 2-core box), s.
MARGIN_S = 0.010


# Multi-process timing on a shared 2-core machine: a scheduling hiccup can miss a bound
# once; two reruns keep CI meaningful (every attempt must fail for a red run).
@pytest.mark.flaky(reruns=2, reruns_delay=2)
def test_killed_decoupling_zeroes_every_controller(ctx, cfg, tmp_path):
    """kill -9 sensor_decoupling: each controller publishes zero force within its timeout."""
    cids = controller_ids(cfg.plant.num_stages)
    probe = Probe(ctx, forces=cids)
    jitter = Jitter()
    graph = Graph(cfg, tmp_path, mode=Mode.DFBC_FFC)
    # the watchdog checks every quarter timeout on the steady clock
    bound = 1.25 * cfg.control.input_timeout_s + MARGIN_S
    try:
        probe.wait(lambda: float(probe.value("plant_simulator", "sim_time_s", "0")) > 2.0,
                   90.0, "plant running")
        probe.wait(lambda: all(probe.value(c, "gain") == "1.000" for c in cids), 10.0,
                   "controllers faded in")
        t_kill = graph.kill("sensor_decoupling")
        after = t_kill + 50_000_000
        probe.wait(lambda: all((probe.status_after(c, after) or ("",))[0].startswith("stale")
                               for c in cids), 10.0, "every controller reports stale input")
        stale_at = {c: int(probe.status_after(c, after)[1]["stale_at_mono_ns"]) for c in cids}
        latency = {c: max(0, t - t_kill) / 1e9 for c, t in stale_at.items()}
        probe.wait(lambda: float(probe.value("plant_simulator", "sim_time_s", "0")) > 0.0
                   and len(probe.applied) > 0, 1.0, "plant alive")
        k_now = int(probe.value("plant_simulator", "sample"))
        probe.wait(lambda: int(probe.value("plant_simulator", "sample", "0")) > k_now + 1000,
                   30.0, "the plant runs on without its sensor path")
        with probe.lock:
            before = {c: np.array([f for t, _, f in probe.forces[c] if t < t_kill])
                      for c in cids}
            # the last 50 commands (in publication order), 0.5 s of plant time after the kill: a
            # twist still queued at the kill may be answered after the first watchdog zero
            late = {c: np.array([f for t, _, f in probe.forces[c] if t > t_kill][-50:])
                    for c in cids}
    finally:
        codes = graph.stop()
        probe.close()
        jitter.close()
    worst = max(latency.values())
    # twice the test thread's overrun: the busy node processes wake later than it does
    load = 2 * jitter.worst(t_kill - 50_000_000, max(stale_at.values()) + 50_000_000)
    report("2", "kill -9 sensor_decoupling (real time, DFBC+FFC)",
           "every controller publishes zero force (watchdog); plant runs on",
           "zero after " + ", ".join(f"{c} {v * 1e3:.1f} ms" for c, v in latency.items())
           + f" (timeout {cfg.control.input_timeout_s * 1e3:g} ms; scheduling delay "
           f"{load * 1e3:.1f} ms)", latency_s=latency, bound_s=bound, sched_delay_s=load)
    for c in cids:
        assert np.abs(before[c]).max() > 0.0, f"{c} produced no force before the kill"
        assert len(late[c]) == 50, f"{c} stopped publishing (the watchdog must go on)"
        assert np.all(late[c] == 0.0), f"{c} published a non-zero force without input"
    assert worst <= bound + load, (f"zero force only after {worst * 1e3:.1f} ms (bound "
                                   f"{bound * 1e3:g} ms + scheduling delay {load * 1e3:.1f} ms)")
    assert all(c == 0 for n, c in codes.items() if n != "sensor_decoupling"), codes
    assert_clean(graph.logs())
