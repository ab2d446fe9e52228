"""One run of the node graph and its timings, for ``graph_bench.py``.

:func:`run_graph` starts the graph (one process per node or composed, with or without a
recorder) through ``dcsms_ros.cli.deploy``, lets the plant step ``seconds`` of simulated time,
and reads what the plant wrote about every sample (``timing_file``: the wall time of each
sample, per controller the time from a sample's publication to the arrival of the force stamped
with it), the CPU of each process (``/proc/<pid>/stat``), the machine's steal time
(``/proc/stat``) and, when recorded, the bag's message counts. :func:`lockstep_rate`,
:func:`realtime_stats` and :func:`p50_us` reduce it.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
CONFIG = HERE.parent / "config" / "table1.yaml"


def _cpu_ticks(pid: int, tid: int | None = None) -> int | None:
    path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
    try:
        fields = Path(path).read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return int(fields[11]) + int(fields[12])  # utime + stime (fields 14, 15)


def _bag_writer(pid: int) -> int | None:
    """The pid of the bag writer process a composed recorded graph ``pid`` started
    (:mod:`dcsms_ros.analysis.bagprocess`), if any: its CPU is the recording's too."""
    try:
        kids = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return None
    return int(kids[0]) if kids else None


def _fifo_thread(pid: int) -> int | None:
    """The kernel id of the process's SCHED_FIFO thread (composed: the driver), if any."""
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    for tid in tids:
        with contextlib.suppress(OSError):
            if os.sched_getscheduler(int(tid)) == os.SCHED_FIFO:
                return int(tid)
    return None


@contextlib.contextmanager
def env(**kv: str) -> Any:
    old = {k: os.environ.get(k) for k in kv}
    os.environ.update(kv)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run_graph(schedule: str, seconds: float, domain: int, tmp: Path, hot: bool = True,
              timeout_s: float = 600.0, on_running: Any = None, rt_priority: int = 0,
              composed: bool = False, record: str | None = None,
              config: Path = CONFIG, rt_cpus: frozenset[int] = frozenset()) -> dict[str, Any]:
    """Start the graph (one process per node, or ``composed``), step ``seconds`` of simulated
    time, return the timings. ``record``: ``process`` or ``composed`` runs the recorder (every
    topic of the graph and /diagnostics) beside it; ``parts`` (one process per node, what
    ``dcsms up --record`` runs) records the per-sample topics in the node processes and the
    rest in a recorder process, merged into one bag at the end.

    ``on_running(kids)`` (e.g. a profiler attaching to ``kid.proc.pid``) is called once the
    plant steps; ``rt_cpus``: the CPUs of the control path's hot threads (``--rt-cpus``)."""
    from dcsms_ros.cli import deploy, processes
    from dcsms_ros.cli.hoststeal import read_cpu_times, steal_fraction
    from dcsms_ros.cli.parts import RECORDER_PART, merge_parts, parts_dir
    from dcsms_ros.core.config import load_config
    from dcsms_ros.core.modes import Mode
    from dcsms_ros.graph import (
        LOCKSTEP_WRITER_DEPTH,
        RECORD_PART_ENV,
        RECORD_TOPICS_ENV,
        define_graph,
    )

    cfg = load_config(config)
    run_dir = Path(tempfile.mkdtemp(prefix=f"graph-{schedule}-", dir=tmp))
    timing = run_dir / "timing.npz"
    spec = define_graph(cfg, schedule=schedule, mode=Mode.DFBC_FFC, duration_s=seconds)
    recorded = [f"{spec.namespace}/*", "/diagnostics"]
    streams = spec.stream_topics() if record == "parts" else []
    if record:  # the run waits for the recorder to listen, as `up` does
        spec = define_graph(cfg, schedule=schedule, mode=Mode.DFBC_FFC, duration_s=seconds,
                            observers=spec.recorded_observed(streams=not streams))
    spec = spec.with_params("plant_simulator", timing_file=str(timing))
    params, graph_file = deploy.write_files(spec, run_dir)
    bag = run_dir / "bag"
    rec: list[processes.Child] = []
    parts = parts_dir(bag)
    if record in ("process", "parts"):
        into = parts / RECORDER_PART if streams else bag
        argv = [*deploy.recorder_command(into, recorded, exclude=streams),
                "--queue-depth", str(LOCKSTEP_WRITER_DEPTH)]
        rec = [processes.Child("recorder", argv)]
    if composed:
        kids = [deploy.composed_child(graph_file, params, rt_priority,
                                      [str(bag), *recorded] if record == "composed" else (),
                                      rt_cpus)]
    else:
        kids = deploy.children(spec, params, rt_priority, rt_cpus)
        for k in kids if streams else []:
            k.env.update({RECORD_PART_ENV: str(parts / k.name),
                          RECORD_TOPICS_ENV: " ".join(streams)})
    plant = kids[-1]
    with env(ROS_DOMAIN_ID=str(domain), DCSMS_HOT_PATH="1" if hot else "0"):
        processes.start(rec, run_dir, verbose=False)
        processes.start(kids, run_dir, verbose=False)
    try:
        assert plant.proc is not None and plant.log is not None
        deadline = time.monotonic() + timeout_s
        cpu0: dict[str, int | None] = {}
        t_cpu0 = 0.0
        host0 = None
        driver: int | None = None  # composed under SCHED_FIFO: its driver thread's CPU
        writer: int | None = None
        wrote: list[tuple[float, int]] = []  # the bag writer's (time, ticks): first, latest
        drv: list[tuple[float, int]] = []  # (time, ticks): the first and the latest
        while plant.proc.poll() is None and time.monotonic() < deadline:
            if not cpu0 and "graph connected" in plant.log.read_text(errors="replace"):
                t_cpu0 = time.monotonic()
                host0 = read_cpu_times()
                cpu0 = {k.name: _cpu_ticks(k.proc.pid) for k in kids + rec
                        if k.proc is not None}
                writer = _bag_writer(plant.proc.pid) if composed and record else None
                if on_running is not None:
                    on_running(kids)
                if composed and rt_priority:
                    driver = _fifo_thread(plant.proc.pid)
            if writer is not None and (ticks := _cpu_ticks(writer)) is not None:
                now = (time.monotonic(), ticks)
                wrote = [wrote[0] if wrote else now, now]
            if driver is not None:
                ticks = _cpu_ticks(plant.proc.pid, driver)
                if ticks is not None:
                    now = (time.monotonic(), ticks)
                    drv = [drv[0] if drv else now, now]
            time.sleep(0.02)
        t_cpu1 = time.monotonic()
        host1 = read_cpu_times()
        cpu1 = {k.name: _cpu_ticks(k.proc.pid) for k in kids + rec if k.proc is not None}
        if plant.proc.poll() is None:
            raise TimeoutError(f"{schedule} graph did not finish within {timeout_s:g} s")
    finally:
        processes.stop_in_turn(kids, processes.RECORDER_STOP_TIMEOUTS if record == "composed" else
                    processes.STOP_TIMEOUTS)
        processes.stop(rec, processes.RECORDER_STOP_TIMEOUTS)
        if streams and merge_parts(parts, bag):
            raise RuntimeError(f"the parts in {parts} could not be merged")
    if plant.proc.returncode != 0 or not timing.exists():
        raise RuntimeError(f"plant exited {plant.proc.returncode}: "
                           f"{plant.log.read_text()[-2000:] if plant.log else ''}")
    z = np.load(timing)
    hz = os.sysconf("SC_CLK_TCK")
    span = max(t_cpu1 - t_cpu0, 1e-9)
    cpu = {n: (b - a) / hz / span for n, a in cpu0.items()
           if a is not None and (b := cpu1.get(n)) is not None}
    c0, c1 = z["cpu_s"]
    t = z["t_pub_ns"].astype(np.float64) * 1e-9
    # the plant's process CPU over its run (composed: every node, the in-process recorder)
    cpu["composed" if composed else "plant_simulator"] = (
        (c1 - c0) / max(t[-1] - t[0], 1e-9) if c1 > c0 else float("nan"))
    if wrote and wrote[1][0] > wrote[0][0]:
        cpu["bag_writer"] = (wrote[1][1] - wrote[0][1]) / hz / (wrote[1][0] - wrote[0][0])
    if drv and drv[1][0] > drv[0][0]:
        cpu["driver"] = (drv[1][1] - drv[0][1]) / hz / (drv[1][0] - drv[0][0])
    lat = np.concatenate([z[k] for k in z.files if k.startswith("lat_ns_")]) * 1e-9
    out = {"t": t, "rate_hz": float(z["rate_hz"]), "cpu": cpu, "latency_s": lat,
           "overruns": int(z["overruns"]), "recorded": None,
           "late": int(z["overruns"]) + int(z["late_steps"] if "late_steps" in z.files else 0),
           "woke_late": int(z["woke_late_steps"]) if "woke_late_steps" in z.files else 0,
           "paused": int(z["paused_steps"]) if "paused_steps" in z.files else 0,
           "stale": int(z["stale_samples"]) if "stale_samples" in z.files else 0,
           "controllers": len([k for k in z.files if k.startswith("lat_ns_")]),
           "steal": steal_fraction(host0, host1)}
    if record and bag.exists():
        from rosbags.rosbag2 import Reader

        with Reader(bag) as r:
            out["recorded"] = {c.topic: c.msgcount for c in r.connections}
        out["published"] = deploy.bag_published(bag)
    return out


def lockstep_rate(r: dict[str, Any]) -> float:
    """Steps per second from sample 10 on (sample 0 waits for the readers to match)."""
    t = r["t"][10:]
    return (t.size - 1) / (t[-1] - t[0])


def realtime_stats(r: dict[str, Any]) -> dict[str, float]:
    """Achieved rate, period percentiles (s), deadline-miss ratio, latency percentiles (s)."""
    t, period = r["t"][10:], 1.0 / r["rate_hz"]
    p = np.diff(t)
    lat = r["latency_s"]
    return {"rate_hz": (t.size - 1) / (t[-1] - t[0]), "p50": float(np.percentile(p, 50)),
            "p99": float(np.percentile(p, 99)), "p999": float(np.percentile(p, 99.9)),
            "max": float(p.max()), "miss": float(np.mean(p > 1.5 * period)),
            "lat50": float(np.percentile(lat, 50)), "lat99": float(np.percentile(lat, 99)),
            "samples": float(t.size)}


def p50_us(r: dict[str, Any]) -> float:
    """Median step interval of a lockstep run (us): robust to the preemptions of a shared
    machine, which the mean rate is not."""
    return float(np.percentile(np.diff(r["t"]), 50) * 1e6)


__all__ = ["CONFIG", "env", "lockstep_rate", "p50_us", "realtime_stats", "run_graph"]
