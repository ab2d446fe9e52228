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

``--charged`` measures instead the machine's pauses that land on a running thread: one
thread spins on the clocks (default scheduler, for ``--seconds``) and every gap of 0.3 ms or
more between two reads is reported with the CPU time charged to the thread across it. A gap
the OS made (another thread had the core, a stop signal) is charged nothing; one the
hypervisor made while the virtual CPU ran the thread is charged in full, as if the thread
had worked (``dcsms_ros/ros/pausemeter.py`` tells those apart only while a loop waits).

``python bench/timer_floor.py [--seconds S] [--work-us W ...] [--rt-priority P]
[--latency-us N] [--charged]``.
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


#: The shortest gap between two clock reads of the spinning thread reported (s).
GAP_S = 3e-4


def charged_gaps(seconds: float) -> dict[str, Any]:
    """Gaps of at least :data:`GAP_S` in a thread that reads the monotonic and its own CPU
    clock back to back for ``seconds``, and the CPU charged to it across each.

    Returns
    -------
    dict
        ``seconds``; ``gaps``: a list of (wall us, charged us) per gap; ``charged``: how
        many were charged at least 80 % of their wall time (the thread was on a core, so
        counted as running, while it did not run: a pause of the virtual machine).
    """
    mono, own = time.monotonic_ns, time.thread_time_ns
    gaps: list[tuple[float, float]] = []

    def run() -> None:
        end = mono() + int(seconds * 1e9)
        w0, c0 = mono(), own()
        while w0 < end:
            w, c = mono(), own()
            if w - w0 >= GAP_S * 1e9:
                gaps.append(((w - w0) * 1e-3, (c - c0) * 1e-3))
            w0, c0 = w, c

    th = threading.Thread(target=run, name="charged-gaps")
    th.start()
    th.join()
    return {"seconds": seconds, "gaps": gaps,
            "charged": sum(1 for w, c in gaps if c >= 0.8 * w)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--work-us", type=float, nargs="+", default=[0.0, 300.0])
    ap.add_argument("--rt-priority", type=int, default=50)
    ap.add_argument("--latency-us", type=int, default=None,
                    help="hold this CPU wake-up latency (us; default: the kernel's)")
    ap.add_argument("--charged", action="store_true",
                    help="the pauses charged to a running thread as CPU, not the floor")
    a = ap.parse_args(argv)
    if a.charged:
        print(json.dumps(charged_gaps(a.seconds)))
        return 0
    for w in a.work_us:
        r = measure(a.seconds, w, a.rt_priority, a.latency_us)
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
