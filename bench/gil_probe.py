"""Which late samples of a composed real-time run coincide with work of the executor's thread.

Composed, one process holds the real-time driver thread (plant, decoupling, controllers, the
in-process recorder) and the executor's thread (timers, services, diagnostics, the trip
judge). Both need the GIL: while the executor's thread runs Python, the woken driver gets it
only at the next forced switch (every ``GIL_SWITCH_S``) and then shares it. This probe runs
``dcsms up --realtime --composed`` with a ``sitecustomize`` (in a temporary directory on
``PYTHONPATH``, not part of the package) that logs, in the composed process,

* every pacer decision (``Pacer.due``): when the plant stepped, which sample was due, how many,
* every executor callback (start, end, thread CPU, name), and each housekeeping job the
  host's one timer runs (``job NAME``; an awaiting job's first part runs in the timer's
  callback, ``Housekeeper._tick``, after the job's own entry ends),
* every wait of the executor's thread in ``rcl_wait`` (start, end),
* every collection of Python's cyclic garbage collector (start, end, generation, thread),

and attributes each late burst (a step computing more than one sample) to what held the GIL
between the first late sample's deadline and the step: a garbage collection (it stops every
thread), else what the executor's thread did: a callback (by name), rclpy's own work around
its wait set (busy, no callback), or nothing (idle: the driver alone).
It is a coincidence count, not a proof of cause; the ``idle`` row bounds what the driver loses
on its own.

Usage: ``python bench/gil_probe.py [--seconds 20] [--config FILE] [--mode M] [--runs N]``;
``--json OUT`` writes the figures.
"""

from __future__ import annotations

import argparse
import bisect
import json
import os
import subprocess
import sys
import tempfile
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: The probe, installed as ``sitecustomize`` in the composed process (rclpy 7.1.6 names).
PROBE_SITE = r'''
import atexit, gc, json, os, threading, time
_OUT = os.environ.get("DCSMS_GIL_PROBE")
if _OUT:
    _LOG = {"due": [], "cb": [], "wait": [], "gc": []}
    _mono = time.monotonic
    _gc_t0 = [0.0]

    def _on_gc(phase, info):
        if phase == "start":
            _gc_t0[0] = _mono()
        else:
            _LOG["gc"].append((_gc_t0[0], _mono(), info["generation"],
                               threading.current_thread().name))

    gc.callbacks.append(_on_gc)

    def _install():
        from dcsms_ros.protocols import pacer
        import rclpy.executors as ex
        due0 = pacer.Pacer.due

        def due(self, now, k, woke_late_s=0.0, paused_s=0.0):
            n = due0(self, now, k, woke_late_s, paused_s)
            if n >= 1:
                _LOG["due"].append((now, self.t0 + k / self.rate, n, 1.0 / self.rate))
            return n

        pacer.Pacer.due = due
        run0 = ex.await_or_execute

        async def await_or_execute(callback, *args):
            t0, c0 = _mono(), time.thread_time()
            try:
                return await run0(callback, *args)
            finally:
                _LOG["cb"].append((t0, _mono(), time.thread_time() - c0,
                                   getattr(callback, "__qualname__", repr(callback))))

        ex.await_or_execute = await_or_execute
        real = ex._rclpy

        class WaitSet(real.WaitSet):
            def wait(self, timeout):
                t0 = _mono()
                try:
                    return super().wait(timeout)
                finally:
                    if threading.current_thread() is threading.main_thread():
                        _LOG["wait"].append((t0, _mono(), time.thread_time()))

        class _Rclpy:
            def __getattr__(self, name):
                return getattr(real, name)

        shim = _Rclpy()
        shim.WaitSet = WaitSet
        ex._rclpy = shim

    _install()

    def _install_jobs():
        # each housekeeping job under its own name (the tick runs several, and an awaiting
        # job's first part inside the tick, after its callback returned the coroutine)
        from dcsms_ros.ros import housekeeping as hk
        start0 = hk.Housekeeper.start

        def start(self):
            for job in self.jobs:
                cb = job.callback
                inner = getattr(cb, "__wrapped__", cb)
                name = "job " + getattr(inner, "__qualname__", repr(inner))

                def timed(cb=cb, name=name):
                    t0, c0 = _mono(), time.thread_time()
                    try:
                        return cb()
                    finally:
                        _LOG["cb"].append((t0, _mono(), time.thread_time() - c0, name))
                job.callback = timed
            return start0(self)

        hk.Housekeeper.start = start

    _install_jobs()

    def _dump():
        if _LOG["due"]:
            with open(f"{_OUT}.{os.getpid()}.json", "w") as f:
                json.dump(_LOG, f)

    atexit.register(_dump)
'''

IDLE = "(executor idle: the driver alone)"
BUSY = "(executor busy, no callback: rclpy's wait-set work)"


def attribute(log: dict[str, list[Sequence[Any]]], busy_share: float = 0.3,
              seconds: float | None = None) -> dict[str, Any]:
    """Attribute the late samples of one run's probe log.

    Parameters
    ----------
    log : dict
        ``due``: ``(now_s, deadline_s, n, period_s)`` per pacer step (``deadline_s``: when the
        newest of the ``n`` samples was due); ``cb``: ``(start_s, end_s, cpu_s, name)`` per
        executor callback; ``wait``: ``(start_s, end_s, thread_cpu_s)`` per wait of the
        executor's thread; ``gc`` (optional): ``(start_s, end_s, generation, thread)`` per
        garbage collection.
    busy_share : float
        A burst with no callback counts as ``BUSY`` when the executor's thread was outside its
        wait for more than this share of the burst's window, else as ``IDLE``.
    seconds : float, optional
        The run's duration: the plant steps no sample beyond it, though the last burst may
        have counted one more as due.

    Returns
    -------
    dict
        ``late``: late samples (all but the newest of each burst); ``causes``: late samples
        per cause (``gc gen N``, callback names joined by ``+``, ``BUSY`` or ``IDLE``);
        ``gc``: collections per generation with their longest pause (ms); ``lateness_ms``:
        quantiles of step time minus the newest sample's deadline; ``executor``: wakes per
        second, CPU share of a core and callback CPU share over the waits' span; ``callbacks``:
        per name, calls, mean wall and mean CPU (us).
    """
    due = log["due"]
    cbs = sorted(log["cb"], key=lambda c: c[0])
    waits = sorted(log["wait"], key=lambda w: w[0])
    w_start = [w[0] for w in waits]
    w_end = [w[1] for w in waits]
    cb_start = [c[0] for c in cbs]
    longest_cb = max((c[1] - c[0] for c in cbs), default=0.0)
    gcs = sorted(log.get("gc", []), key=lambda g: g[0])
    gc_start = [g[0] for g in gcs]
    longest_gc = max((g[1] - g[0] for g in gcs), default=0.0)
    causes: Counter[str] = Counter()
    late = 0
    for now, deadline, n, period in due:
        if n <= 1:
            continue
        late += n - 1
        first = deadline - (n - 1) * period  # the first late sample's deadline
        span = max(now - first, 1e-9)
        gens = {int(g[2]) for g in gcs[bisect.bisect_left(gc_start, first - longest_gc):
                                        bisect.bisect_right(gc_start, now)] if g[1] > first}
        if gens:
            causes[f"gc gen {max(gens)}"] += n - 1
            continue
        names = set()
        for c in cbs[bisect.bisect_left(cb_start, first - longest_cb):
                     bisect.bisect_right(cb_start, now)]:
            if c[1] > first:
                names.add(str(c[3]))
        if names:
            causes["+".join(sorted(names))] += n - 1
            continue
        waited = 0.0
        for w in waits[max(bisect.bisect_left(w_end, first) - 1, 0):
                       bisect.bisect_right(w_start, now) + 1]:
            waited += max(min(w[1], now) - max(w[0], first), 0.0)
        causes[BUSY if span - waited > busy_share * span else IDLE] += n - 1
    lateness = sorted(now - deadline for now, deadline, _, _ in due)

    def q(p: float) -> float:
        return lateness[int(p * (len(lateness) - 1))] * 1e3 if lateness else float("nan")

    executor: dict[str, float] = {}
    if len(waits) > 1:
        span_s = waits[-1][1] - waits[0][1]
        cpu = waits[-1][2] - waits[0][2]
        cb_cpu = sum(c[2] for c in cbs if waits[0][1] <= c[0] <= waits[-1][1])
        executor = {"wakes_per_s": len(waits) / span_s, "cpu_share": cpu / span_s,
                    "callback_cpu_share": cb_cpu / span_s}
    per: dict[str, list[Sequence[Any]]] = defaultdict(list)
    for c in cbs:
        per[str(c[3])].append(c)
    callbacks = {k: {"calls": len(v), "wall_us": sum(c[1] - c[0] for c in v) / len(v) * 1e6,
                     "cpu_us": sum(c[2] for c in v) / len(v) * 1e6}
                 for k, v in per.items()}
    gc_stats: dict[str, dict[str, float]] = {}
    for g in gcs:
        st = gc_stats.setdefault(f"gen {int(g[2])}", {"count": 0, "max_ms": 0.0})
        st["count"] += 1
        st["max_ms"] = max(st["max_ms"], (g[1] - g[0]) * 1e3)
    stepped = sum(d[2] for d in due)
    if seconds is not None and due:
        stepped = min(stepped, round(seconds / due[0][3]))
    return {"samples_stepped": stepped, "late": late, "causes": dict(causes),
            "gc": gc_stats,
            "lateness_ms": {"p50": q(0.5), "p99": q(0.99), "max": q(1.0)},
            "executor": executor, "callbacks": callbacks}


def run_once(seconds: float, config: Path, mode: str, rt_priority: int, tmp: Path,
             domain: int) -> tuple[dict[str, Any], str]:
    """One probed composed real-time run; returns the attribution and the summary line."""
    site = tmp / "site"
    site.mkdir(exist_ok=True)
    (site / "sitecustomize.py").write_text(PROBE_SITE)
    prefix = tmp / f"probe{len(list(tmp.iterdir()))}"
    env = dict(os.environ, DCSMS_GIL_PROBE=str(prefix),
               PYTHONPATH=os.pathsep.join([str(site), str(ROOT),
                                           os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep))
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env["ROS_DOMAIN_ID"] = str(domain)
    cmd = [sys.executable, "-m", "dcsms_ros.cli", "up", "--realtime", "--composed",
           "--rt-priority", str(rt_priority), "--mode", mode, "--duration", str(seconds),
           "--record", str(tmp / f"{prefix.name}.bag"), "--config", str(config)]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=seconds + 120,
                       check=False)
    summary = next((ln for ln in p.stderr.splitlines() + p.stdout.splitlines()
                    if "summary:" in ln), "")
    if p.returncode != 0:
        raise RuntimeError(f"dcsms up exited {p.returncode}: {p.stderr.strip()[-400:]}")
    dumps = sorted(tmp.glob(f"{prefix.name}.*.json"), key=lambda f: f.stat().st_size)
    if not dumps:
        raise RuntimeError("the composed process left no probe log (did it exit normally?)")
    return attribute(json.loads(dumps[-1].read_text()), seconds=seconds), summary


def report(res: dict[str, Any], summary: str) -> str:
    """The attribution of one run as text."""
    lines = [summary.strip(), f"late samples (probe): {res['late']} of {res['samples_stepped']}"]
    total = max(res["late"], 1)
    for name, n in sorted(res["causes"].items(), key=lambda kv: -kv[1]):
        lines.append(f"  {n:7d} ({n / total * 100:5.1f} %)  {name}")
    lat = res["lateness_ms"]
    lines.append(f"step time after the newest due sample's deadline, ms: p50 {lat['p50']:.3f}, "
                 f"p99 {lat['p99']:.3f}, max {lat['max']:.3f}")
    for gen, st in sorted(res["gc"].items()):
        lines.append(f"garbage collections {gen}: {st['count']:.0f}, longest {st['max_ms']:.2f} ms")
    ex = res["executor"]
    if ex:
        lines.append(f"executor thread: {ex['wakes_per_s']:.1f} wakes/s, "
                     f"{ex['cpu_share'] * 100:.1f} % of a core "
                     f"({ex['callback_cpu_share'] * 100:.1f} % in callbacks)")
    top = sorted(res["callbacks"].items(), key=lambda kv: -kv[1]["calls"] * kv[1]["cpu_us"])
    for name, c in top[:6]:
        lines.append(f"  {name}: {c['calls']} calls, {c['wall_us']:.0f} us wall, "
                     f"{c['cpu_us']:.0f} us CPU each")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="run length, s (default 20)")
    ap.add_argument("--config", type=Path, default=ROOT / "config" / "table1.yaml")
    ap.add_argument("--mode", default="DFBC+FFC")
    ap.add_argument("--rt-priority", type=int, default=50)
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--domain", type=int, default=int(os.environ.get("DCSMS_BENCH_DOMAIN", "91")))
    ap.add_argument("--json", type=Path, default=None, help="write the attributions here")
    a = ap.parse_args(argv)
    if not a.config.is_file():
        print(f"gil_probe: error: no such configuration: {a.config}", file=sys.stderr)
        return 2
    out = []
    with tempfile.TemporaryDirectory(prefix="dcsms-gil-probe-") as tmp:
        for i in range(a.runs):
            try:
                res, summary = run_once(a.seconds, a.config, a.mode, a.rt_priority,
                                        Path(tmp), a.domain)
            except (RuntimeError, subprocess.TimeoutExpired) as exc:
                print(f"gil_probe: error: run {i + 1}: {exc}", file=sys.stderr)
                return 1
            print(f"-- run {i + 1}\n{report(res, summary)}", flush=True)
            out.append({"summary": summary, **res})
    if a.json is not None:
        a.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
