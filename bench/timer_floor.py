"""The machine's floor for a periodic real-time thread: how many 2 kHz samples an ideal worker
finishes late.

One thread under SCHED_FIFO (as the graph's driver) sleeps to each deadline of a 500 us
period, then spins for a constant ``work`` us, never more, never less. A sample is late when
it finishes after the next deadline, the graph's definition; a late sample's successors whose
deadlines passed meanwhile are skipped and late too, as the graph's pacer does. No Python
varies here, so what is late comes from the machine: the kernel's and the hypervisor's
wake-up of the thread and the time the core is taken from it. ``--latency-us N`` holds the CPU
wake-up latency as ``DCSMS_CPU_LATENCY_US=N`` makes the graph hold it
(``dcsms_ros/ros/cpulatency.py``).

``python bench/timer_floor.py [--seconds S] [--work-us W ...] [--rt-priority P]
[--latency-us N]``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dcsms_ros.ros.cpulatency import CpuLatencyRequest

PERIOD_S = 5e-4


def measure(seconds: float, work_us: float, rt_priority: int = 50,
            latency_us: int | None = None) -> dict[str, Any]:
    """Late samples of an ideal worker of ``work_us`` us per 500 us sample over ``seconds``.

    Returns
    -------
    dict
        ``samples``, ``late``, ``late_ratio``; ``wake_us`` p50 / p99 / p99.9 of the wake-up
        after each deadline (us); ``fifo`` and ``latency_held`` (what was granted: SCHED_FIFO
        ``rt_priority``, the CPU wake-up latency ``latency_us``; None: not held).
    """
    n = int(round(seconds / PERIOD_S))
    work = work_us * 1e-6
    out: dict[str, Any] = {"fifo": False, "latency_held": None}
    req = None
    if latency_us is not None:
        try:
            req = CpuLatencyRequest(latency_us)
            out["latency_held"] = latency_us
        except OSError:
            pass

    def run() -> None:
        if rt_priority:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
                out["fifo"] = True
            except OSError:
                pass
        pc, sleep = time.perf_counter, time.sleep
        wake = np.empty(n)
        late = 0
        t0 = pc() + 0.01
        i = w = 0
        while i < n:
            due = t0 + i * PERIOD_S
            d = due - pc()
            if d > 0:
                sleep(d)
            start = pc()
            wake[w] = start - due
            w += 1
            while pc() - start < work:
                pass
            nxt = i + 1
            end = pc()
            if end > t0 + nxt * PERIOD_S:
                skip_to = min(int((end - t0) / PERIOD_S) + 1, n)
                late += skip_to - i  # this one and those whose deadline passed meanwhile
                nxt = skip_to
            i = nxt
        out["late"] = late
        out["wake_us"] = [float(q) for q in np.percentile(wake[:w] * 1e6, [50, 99, 99.9])]

    try:
        th = threading.Thread(target=run, name="floor")
        th.start()
        th.join()
    finally:
        if req is not None:
            req.close()
    out.update(samples=n, work_us=work_us, late_ratio=out["late"] / n)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--work-us", type=float, nargs="+", default=[0.0, 300.0])
    ap.add_argument("--rt-priority", type=int, default=50)
    ap.add_argument("--latency-us", type=int, default=None,
                    help="hold this CPU wake-up latency (us; default: the kernel's)")
    a = ap.parse_args(argv)
    for w in a.work_us:
        r = measure(a.seconds, w, a.rt_priority, a.latency_us)
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
