"""Node graph: lockstep steps/s and the real-time graph at 2 kHz, next to the ping-pong bound.

Every figure is measured in this run: the rclpy ping-pong bound (``pingpong.py``, default
executor on both sides), the same ping-pong with the echo on rclpy's ``EventsExecutor`` and with
both sides on the hot path (``dcsms_ros/ros/hotpath.py``), then the six-process graph
(plant, decoupling, fb_stage1, fb_stage2, ff_stage1, mode_switch; table1, DFBC+FFC) in lockstep
with the hot path on and off (``DCSMS_HOT_PATH=0``: every subscription on the default
executor), then in real time at ``plant.rate_hz`` for ``--rt-seconds``; the composed graph
beside it (its real time in repeated runs, each beside the machine's floor:
``composed_realtime.py``); last the user's per-process real-time command and the CPU per node
and sample (``per_process_bench.py``).

Each graph run and its timings come from ``graph_run.py``: lockstep rate, real-time period
percentiles, deadline misses (period > 1.5 T) and sensor-to-force latency from the plant's
timing file; CPU share per node from ``/proc/<pid>/stat`` over the stepping phase.
``python bench/graph_bench.py [--smoke] [--rt-seconds S]``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

import composed_realtime
import timer_floor
from graph_run import CONFIG, env, lockstep_rate, p50_us, realtime_stats, run_graph
from per_process_bench import per_process_rows

from dcsms_ros.ros.cpulatency import latency_from_env

Row = dict[str, Any]


def _pp(seconds: float, domain: int, executor: str, ping: str = "single") -> dict[str, Any]:
    import pingpong

    try:
        return pingpong.measure(seconds, domain, executor, timeout_s=20.0, ping=ping)
    except (TimeoutError, RuntimeError) as exc:
        return {"round_trips_per_s": 0.0, "error": str(exc), "round_trips": 0,
                "rtt_us_p50": float("nan"), "rtt_us_p99": float("nan")}


def run(smoke: bool, tmp: Path, rt_seconds: float | None = None) -> list[Row]:
    """Rows: ping-pong variants, lockstep hot/default, real time; all in this run.
    ``rt_seconds``: length of the real-time runs (``--rt-seconds``; default 60 s, smoke 3 s)."""
    from dcsms_ros.rosenv import keep_discovery_local

    keep_discovery_local()  # this process's probes; the graph's processes get it from deploy
    base = int(os.environ.get("DCSMS_BENCH_DOMAIN", 150 + os.getpid() % 50))
    pp_s = 1.0 if smoke else 5.0
    ls_s = 0.5 if smoke else 5.0
    rt_s = rt_seconds if rt_seconds is not None else (3.0 if smoke else 60.0)
    rows: list[Row] = []
    bound = _pp(pp_s, base, "single")
    b = bound["round_trips_per_s"]
    rows.append({"name": "graph: rclpy ping-pong bound (default executors)", "value": b,
                 "unit": "round trips/s",
                 "note": f"RTT p50 {bound['rtt_us_p50']:.0f} us, p99 {bound['rtt_us_p99']:.0f}"})
    for ex, ping, label in (("events", "single", "echo on EventsExecutor"),
                            ("hot", "hot", "both sides on the hot path")):
        r = _pp(pp_s, base + 1, ex, ping)
        rows.append({"name": f"graph: ping-pong, {label}", "value": r["round_trips_per_s"],
                     "unit": "round trips/s", "baseline_name": "default executors",
                     "baseline": b, "note": r.get("error") or
                     f"RTT p50 {r['rtt_us_p50']:.0f} us, {r['round_trips']} round trips"})
    rate = {}
    for hot in (True, False):
        # the hot path against its bound: repeated, each run right after a ping-pong, since
        # single runs of either moved by 30 % within an hour (docs/performance.md)
        rates, bounds = [], []
        for _ in range(HOT_REPEATS if hot and not smoke else 1):
            if hot and not smoke:
                bounds.append(_pp(pp_s, base, "single")["round_trips_per_s"])
            r = run_graph("lockstep", ls_s, base + 2 + hot, tmp, hot=hot)
            rates.append(lockstep_rate(r))
        rate[hot] = statistics.median(rates)
        bb = statistics.median(bounds) if bounds else b
        each = (f"median of {len(rates)} runs ({' / '.join(f'{x:,.0f}' for x in rates)}), each "
                f"after a ping-pong ({' / '.join(f'{x:,.0f}' for x in bounds)}; the bound is "
                f"their median); " if bounds else "")
        cpu = ", ".join(f"{n} {100 * c:.0f}%" for n, c in sorted(r["cpu"].items()))
        lat = r["latency_s"]
        rows.append({
            "name": f"graph: lockstep DFBC+FFC, 6 processes, "
                    f"{'hot path' if hot else 'default executor only'}",
            "value": rate[hot], "unit": "steps/s", "baseline_name": "ping-pong bound",
            "baseline": bb, "target": 2000.0 if hot else None,
            "target_ratio": 0.6 if hot else None,
            "note": f"{each}real-time factor {rate[hot] / 2000.0:.2f}x at 2 kHz; the last run's "
                    f"step p50 {np.percentile(np.diff(r['t']), 50) * 1e6:.0f} us, "
                    f"sample->force p50 {np.percentile(lat, 50) * 1e6:.0f} us, CPU {cpu}"
                    + (f"; {LOCKSTEP_PP_WHY}" if hot and rate[hot] < 2000.0 else "")
                    + (f"; {_ratio_why(rate[hot], bb, r['cpu'])}"
                       if hot and rate[hot] < 0.6 * bb else "")})
    if not smoke:
        # the same, control path under SCHED_FIFO (`dcsms up --rt-priority 50`): lockstep is
        # latency-bound, and a woken real-time thread runs at once
        r = run_graph("lockstep", ls_s, base + 6, tmp, rt_priority=50)
        fifo_rate = lockstep_rate(r)
        cpu = ", ".join(f"{n} {100 * c:.0f}%" for n, c in sorted(r["cpu"].items()))
        rows.append({
            "name": "graph: lockstep DFBC+FFC, 6 processes, hot path, --rt-priority 50",
            "value": fifo_rate, "unit": "steps/s", "baseline_name": "default scheduler",
            "baseline": rate[True], "target": 2000.0,
            "note": f"{fifo_rate / b:.0%} of the ping-pong bound (measured with the default "
                    f"scheduler); real-time factor {fifo_rate / 2000.0:.2f}x; step p50 "
                    f"{np.percentile(np.diff(r['t']), 50) * 1e6:.0f} us; CPU {cpu}"
                    + (f"; {LOCKSTEP_PP_WHY}" if fifo_rate < 2000.0 else "")})
    rows.append({"name": "graph: lockstep real-time factor at 2 kHz (hot path)",
                 "value": rate[True] / 2000.0, "unit": "x real time",
                 "baseline_name": "default executor only", "baseline": rate[False] / 2000.0,
                 "target": 1.0, "note": LOCKSTEP_PP_WHY if rate[True] < 2000.0 else ""})
    r = run_graph("realtime", rt_s, base + 4, tmp, timeout_s=rt_s * 3 + 120)
    s = realtime_stats(r)
    rows += _realtime_rows(r, s, rt_s, "")
    if not smoke:
        # the control path under SCHED_FIFO (`dcsms up --rt-priority 50`), same length, next
        r2 = run_graph("realtime", rt_s, base + 5, tmp, timeout_s=rt_s * 3 + 120, rt_priority=50)
        s2 = realtime_stats(r2)
        fifo = _realtime_rows(r2, s2, rt_s, ", --rt-priority 50 (SCHED_FIFO)")
        for row, (key, scale) in zip(fifo, (("rate_hz", 1.0), ("miss", 1.0), ("lat99", 1e3)),
                                      strict=True):
            row["baseline_name"] = "default scheduler"
            row["baseline"] = s[key] * scale
        fifo[0]["target"] = 0.999 * r2["rate_hz"]  # absolute: the nominal rate, as above
        fifo[0].pop("target_ratio")
        rows += fifo
    rows += composed_rows(smoke, tmp, base, rt_s)
    rows += per_process_rows(smoke, tmp, base, min(rt_s, 20.0))
    return rows


#: Runs of the per-process hot-path lockstep row, each after its own ping-pong bound: single
#: runs gave 0.46-0.95 of the bound across nine benches, and 1,947-2,860 steps/s (old code) /
#: 2,085-3,142 (new) in seven alternating pairs within 20 minutes (docs/performance.md).
HOT_REPEATS = 3
#: Why one process per node misses real time in lockstep (the per-process lockstep rows).
LOCKSTEP_PP_WHY = ("NOT met: each lockstep step waits for three hops in sequence between "
                   "processes (plant to decoupling, to the controllers, back to the plant), "
                   "each a wake-up in another process (the relay row: its CPU alone; "
                   "docs/performance.md); the composed graph is the lockstep deployment for "
                   "speed (its rows)")


def _ratio_why(steps_per_s: float, bound: float, cpu: dict[str, float]) -> str:
    """Why a lockstep rate is below 0.6 of the ping-pong bound, from this run's figures."""
    hops_us = 1.5e6 / bound  # three messages in series, where a round trip is two
    work = ", ".join(f"{n} {cpu[n] / steps_per_s * 1e6:.0f} us"
                     for n in ("plant_simulator", "sensor_decoupling") if n in cpu)
    return (f"below 0.6 of the bound: a step is three messages in series where a round trip "
            f"is two, so with an echo's work it would reach 0.67 of the bound; at the "
            f"ping-pong's pace the hops take {hops_us:.0f} us of the {1e6 / steps_per_s:.0f} "
            f"us step, the rest is what the plant and the decoupling do above an echo (their "
            f"CPU a step, wake-ups included: {work})")


#: What the deadline-miss rows measure, beside issue 21's late + stale.
MISS_WHY = ("the jitter of the plant's publication period; a late period is caught up within "
            "20 samples, so it is not a late sample (issue 21 counts late + stale: "
            "docs/performance.md)")

def _recorded(r: dict[str, Any], samples: int) -> str:
    """What the recorder got of the stream topics (lockstep: every sample, nothing lost)."""
    rec = r.get("recorded") or {}
    streams = {t: c for t, c in rec.items() if "/velocity/" in t or "/force/" in t
               or t.endswith(("/sensors/raw", "/actuators/applied"))}
    sent = r.get("published") or {}
    if sent and all(t in sent for t in streams):  # real time: against what was published
        lost = {t: sent[t] - c for t, c in streams.items() if c < sent[t]}
        return (f"recorded {sum(streams.values())} of {sum(sent[t] for t in streams)} stream "
                f"messages published" + (f", LOST: {lost}" if lost else ", none lost"))
    short = {t: c for t, c in streams.items() if c < samples}
    return (f"recorded {sum(rec.values())} msgs on {len(rec)} topics, "
            + (f"SHORT: {short}" if short else f"every stream complete ({samples} samples)"))


#: Alternating runs of the per-process and the composed lockstep graph whose medians the
#: lockstep rows report: single 10 s runs of each moved by up to 25 % within an hour
#: (docs/performance.md), more than the gap to the targets; five since three fell by 35 %
#: within one row.
LOCKSTEP_REPEATS = 5
#: Ratio of the fastest to the slowest composed run above which the row's note says its runs
#: scattered: in one bench three runs fell 8,244 -> 6,651 -> 5,396 steps/s (step p50 133 us)
#: and ran 9,774 / 9,103 / 8,918 (67-69 us) re-run minutes later (docs/performance.md).
LOCKSTEP_SCATTER = 1.2


def composed_rows(smoke: bool, tmp: Path, base: int, rt_s: float) -> list[Row]:
    """Composed against one process per node, recording on, in this run; 6-DOF; real time
    composed; `dcsms demo --composed` end to end."""
    ls_s = 0.5 if smoke else 10.0
    rows: list[Row] = []
    runs = {}
    if smoke:  # a few seconds: the composed path runs at all, recording included
        r = run_graph("lockstep", ls_s, base + 10, tmp, composed=True, record="composed")
        return [{"name": "graph: lockstep DFBC+FFC, composed, recorder in the same process",
                 "value": lockstep_rate(r), "unit": "steps/s",
                 "note": _recorded(r, int(round(ls_s * 2000)))}]
    each: dict[str, list[float]] = {"process": [], "composed+rec": []}
    for _ in range(LOCKSTEP_REPEATS):  # alternating: both kinds see the same hours
        for key, domain, composed, record in (("process", base + 10, False, "parts"),
                                              ("composed+rec", base + 11, True, "composed")):
            r = run_graph("lockstep", ls_s, domain, tmp, composed=composed, record=record)
            each[key].append(lockstep_rate(r))
            runs[key] = r  # the notes' details: the last run of each kind
    rates: dict[str, float] = {k: statistics.median(v) for k, v in each.items()}
    spread = {k: " / ".join(f"{x:,.0f}" for x in v) for k, v in each.items()}
    r = run_graph("lockstep", ls_s, base + 12, tmp, composed=True, record="process")
    rates["composed"], runs["composed"] = lockstep_rate(r), r
    n = int(round(ls_s * 2000))
    cpu = {k: ", ".join(f"{a} {100 * c:.0f}%" for a, c in sorted(r["cpu"].items()))
           for k, r in runs.items()}
    rows.append({"name": "graph: lockstep DFBC+FFC, 6 processes, recording on",
                 "value": rates["process"], "unit": "steps/s",
                 "note": f"median of {LOCKSTEP_REPEATS} runs ({spread['process']}), alternating "
                         f"with the composed row's; {_recorded(runs['process'], n)}; CPU "
                         f"{cpu['process']}"})
    rows.append({"name": "graph: lockstep DFBC+FFC, composed, recording on (recorder in the "
                         "process, the default)",
                 "value": rates["composed+rec"], "unit": "steps/s",
                 "baseline_name": "6 processes, recording on", "baseline": rates["process"],
                 "target": 5000.0, "target_ratio": 5.0,
                 "note": f"median of {LOCKSTEP_REPEATS} runs ({spread['composed+rec']}); "
                         f"{rates['composed+rec'] / 2000:.2f}x real time at 2 kHz; step p50 "
                         f"{p50_us(runs['composed+rec']):.0f} us; "
                         f"{_recorded(runs['composed+rec'], n)}; CPU {cpu['composed+rec']}"
                         + _lockstep_why(rates["composed+rec"], rates["process"],
                                         each["composed+rec"])})
    rows.append({"name": "graph: lockstep DFBC+FFC, composed, recorder process",
                 "value": rates["composed"], "unit": "steps/s",
                 "baseline_name": "recorder in the process", "baseline": rates["composed+rec"],
                 "note": f"step p50 {p50_us(runs['composed']):.0f} us (every message also "
                         f"published on DDS for the recorder); {_recorded(runs['composed'], n)}; "
                         f"CPU {cpu['composed']}"})
    tem_s = 0.5 if smoke else 5.0
    tem = run_graph("lockstep", tem_s, base + 14, tmp, composed=True, record="composed",
                    config=CONFIG.parent / "tem_paper_fit.yaml")
    rate = lockstep_rate(tem)
    rows.append({"name": "graph: lockstep 6dof TEM (tem_paper_fit) DFBC+FFC, composed, "
                         "recording on",
                 "value": rate / 2000.0, "unit": "x real time", "target": 1.0,
                 "note": f"{rate:.0f} steps/s; {_recorded(tem, int(round(tem_s * 2000)))}"})
    rows.append(_up_row(smoke, tmp, base + 16))
    # recording on, in the process (`dcsms up --composed --record`'s default), repeated,
    # each run beside the machine's floor
    held = latency_from_env()[0]  # as the graph's runs hold it
    secs, rt_runs, floors, idle = composed_realtime.measure(smoke, tmp, base + 15,
                                                            min(rt_s, 20.0),
                                                            timer_floor.measure, held)
    kept = [_recorded(r, int(round(secs * r["rate_hz"]))) for r in rt_runs]
    short = [k for k in kept if not k.endswith("none lost")]
    rows += composed_realtime.rows(
        secs, rt_runs, floors, idle, "; ".join(short) if short else
        f"every stream message published was recorded, in {len(rt_runs)} of {len(rt_runs)} runs",
        held, _realtime_rows)
    rows.append(_demo_row(smoke, tmp))
    return rows


def _lockstep_why(composed: float, process: float, runs: Sequence[float] = ()) -> str:
    """Why the composed lockstep row misses its targets (nothing when it meets them); with
    its ``runs`` (steps/s), whether they scattered more than :data:`LOCKSTEP_SCATTER`."""
    why = []
    if composed < 5000.0:
        why.append("below 5,000 steps/s (2.5x real time)")
    if composed < 5.0 * process:
        why.append(f"below 5x the 6 processes ({5.0 * process / composed - 1:.0%} missing)")
    if not why:
        return ""
    scatter = ""
    if runs and max(runs) > LOCKSTEP_SCATTER * min(runs):
        scatter = (f"; its runs differ by {max(runs) / min(runs) - 1:.0%} (the machine's speed "
                   "moved within the row: re-run it before reading the ratio)")
    return (f"; NOT met, {' and '.join(why)}{scatter}"
            ": the step is one Python thread doing every node's work, spread thin (py-spy, the "
            "plant's, the decoupling's and the controllers' samples compiled: plant 37 %, "
            "controllers 22 % (their kernel 7 %), decoupling 15 %, checkpoints 7 %; no source "
            "line above 3 %); recording costs the driver ~14 us a step since its bag is written "
            "by a bag writer process (80 against 66 us unrecorded in a same-run pair; 25 us "
            "before: performance.md, the bag writer process): the bus's batches framed into "
            "a pipe, and the true twists published for the recorder only; it is preempted on "
            "a shared machine (performance.md, the composed lockstep step); the compiled plant and "
            "decoupling made the 6 processes faster too (5-6 %), and host lanes 7-14 % before "
            "(same-run pairs, performance.md)")


def _up_row(smoke: bool, tmp: Path, domain: int) -> Row:
    """`dcsms up --composed --lockstep --duration 30 --record OUT` (table1), wall time from the
    command to its exit: start-up, 30 s of samples, the bag closed."""
    import subprocess

    seconds = 1.0 if smoke else 30.0
    out = Path(tempfile.mkdtemp(prefix="up-", dir=tmp)) / "bag"
    argv = [sys.executable, "-m", "dcsms_ros.cli", "up", "--composed", "--lockstep", "--mode",
            "DFBC+FFC", "--duration", str(seconds), "--record", str(out)]
    t0 = time.perf_counter()
    with env(ROS_DOMAIN_ID=str(domain)):
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
    wall = time.perf_counter() - t0
    tail = [ln for ln in proc.stdout.splitlines() if "summary" in ln]
    return {"name": f"graph: `dcsms up --composed --lockstep --duration {seconds:g} --record`, "
                    f"end to end", "value": seconds / wall, "unit": "x real time",
            "target": 1.5, "note": f"{wall:.1f} s wall; exit {proc.returncode}; "
                                   f"{tail[-1] if tail else proc.stderr[-300:]}"}


def _demo_row(smoke: bool, tmp: Path) -> Row:
    """`dcsms demo --composed --rt-priority 50` (what `make demo` runs), wall time. Since the
    demo runs the paper's TEM experiment (150 s simulated) the target is 5 min; the 90 s of
    the composed-graph issue was for the 1-DOF demo of 78 s simulated."""
    import subprocess

    out = Path(tempfile.mkdtemp(prefix="demo-", dir=tmp)) / "demo"
    argv = [sys.executable, "-m", "dcsms_ros.cli", "demo", "--out", str(out), "--composed",
            "--rt-priority", "50"]
    if smoke:
        argv += ["--modes", "Passive,FBC", "--segment", "0.5", "--settle", "0.5"]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=1800, check=False)
    wall = time.perf_counter() - t0
    tail = [ln for ln in proc.stdout.splitlines() if "simulated and recorded" in ln]
    return {"name": "demo: `dcsms demo --composed --rt-priority 50` (make demo), end to end",
            "value": wall, "unit": "s", "target_max": 300.0,
            "note": f"exit {proc.returncode}; {tail[-1] if tail else proc.stderr[-300:]}"}


def _realtime_rows(r: dict[str, Any], s: dict[str, float], rt_s: float,
                   label: str) -> list[Row]:
    """Achieved rate, deadline-miss ratio and latency rows of one real-time run."""
    cpu = ", ".join(f"{n} {100 * c:.0f}%" for n, c in sorted(r["cpu"].items()))
    per = (f"period p50/p99/p99.9/max {s['p50'] * 1e6:.0f}/{s['p99'] * 1e6:.0f}/"
           f"{s['p999'] * 1e6:.0f}/{s['max'] * 1e6:.0f} us")
    taken = r["latency_s"].size / max(s["samples"] * r["controllers"], 1)
    return [
        {"name": f"graph: real time {rt_s:g} s{label}, achieved rate", "value": s["rate_hz"],
         "unit": "Hz", "baseline_name": "nominal", "baseline": r["rate_hz"],
         "target_ratio": 0.999, "note": f"{per}; CPU {cpu}; catch-up overruns {r['overruns']}"},
        {"name": f"graph: real time{label}, deadline-miss ratio (period > 1.5 T)",
         "value": s["miss"], "unit": "", "target_max": 1e-3, "note": f"{per}; {MISS_WHY}"},
        {"name": f"graph: real time{label}, sensor-to-force latency p99",
         "value": s["lat99"] * 1e3, "unit": "ms", "baseline_name": "p50",
         "baseline": s["lat50"] * 1e3, "target_max": 1.0,
         "note": f"{r['latency_s'].size} forces taken by the plant, {taken:.0%} of samples x "
                 f"controllers; from the plant's publication of a sample to its arrival at the "
                 f"plant"},
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--rt-seconds", type=float, default=None)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="dcsms-graph-") as tmp:
        rows = run(a.smoke, Path(tmp), a.rt_seconds)
    import run as harness

    print(harness.table(rows))
    print(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
