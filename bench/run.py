"""dcsms_ros benchmark harness: one table, every figure next to its same-run baseline.

``python bench/run.py`` (``make bench``) runs every registered benchmark and writes
``bench/results.json`` (machine info + rows); ``--smoke`` runs tiny sizes in a few seconds
(CI checks only that it runs and writes well-formed JSON, never its timings).

A benchmark is a function ``run(smoke, tmp) -> list[row]`` registered in :data:`REGISTRY`;
a row is a dict with ``name``, ``value``, ``unit``, ``baseline_name``, ``baseline`` and
optionally ``target`` (value >= target), ``target_ratio`` (value / baseline >= it),
``target_max`` (value <= it) and ``note``. The graph figures (lockstep, real time, executor
comparison) come from ``bench/graph_bench.py``.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import importlib.util
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

Row = dict[str, Any]


def _engine(smoke: bool, tmp: Path) -> list[Row]:
    import engine_bench

    return engine_bench.run(smoke)


def _bags(smoke: bool, tmp: Path) -> list[Row]:
    import bag_bench

    return bag_bench.run(smoke, tmp)


def _pingpong(smoke: bool, tmp: Path) -> list[Row]:
    if importlib.util.find_spec("rclpy") is None:
        return [{"name": "rclpy ping-pong", "value": None, "unit": "round trips/s",
                 "note": "rclpy not importable: skipped"}]
    import pingpong

    domain = int(os.environ.get("DCSMS_BENCH_DOMAIN", 100 + os.getpid() % 100))
    r = pingpong.measure(1.0 if smoke else 10.0, domain)
    return [{"name": "rclpy ping-pong bound, TwistStamped, 2 processes",
             "value": r["round_trips_per_s"], "unit": "round trips/s",
             "note": f"RTT p50 {r['rtt_us_p50']:.0f} us, p99 {r['rtt_us_p99']:.0f} us, "
                     f"{r['round_trips']} round trips"}]


def _graph(smoke: bool, tmp: Path, rt_seconds: float | None = None) -> list[Row]:
    """``rt_seconds``: ``--rt-seconds``, the real-time graph run's length (default 60 s, smoke
    3 s)."""
    if not (HERE / "graph_bench.py").exists():
        return [{"name": "lockstep / real-time graph", "value": None, "unit": "",
                 "note": "bench/graph_bench.py not written yet (needs the node graph)"}]
    import graph_bench

    return list(graph_bench.run(smoke, tmp, rt_seconds))


def _supervisor(smoke: bool, tmp: Path) -> list[Row]:
    import supervisor_bench

    return supervisor_bench.run(smoke)


def _stream(smoke: bool, tmp: Path) -> list[Row]:
    import stream_bench

    return stream_bench.run(smoke, tmp)


#: name -> benchmark; run in this order.
REGISTRY: dict[str, Callable[[bool, Path], list[Row]]] = {
    "engine": _engine, "bags": _bags, "stream": _stream, "pingpong": _pingpong,
    "supervisor": _supervisor,
    "graph": _graph,
}


def machine() -> dict[str, Any]:
    """CPU model, cores, Python and library versions, date."""
    import numpy

    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    info: dict[str, Any] = {
        "cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
        "numpy": numpy.__version__, "platform": platform.platform(),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    from importlib.metadata import PackageNotFoundError, version

    for mod in ("numba", "scipy", "rosbags"):
        try:
            info[mod] = version(mod)
        except PackageNotFoundError:
            info[mod] = None
    try:
        info["load_avg"] = os.getloadavg()
    except OSError:
        pass
    return info


def _verdict(r: Row) -> str:
    v, b = r.get("value"), r.get("baseline")
    if v is None:
        return "-"
    ok = []
    if r.get("target") is not None:
        ok.append(v >= r["target"])
    if r.get("target_ratio") is not None and b:
        ok.append(v / b >= r["target_ratio"])
    if r.get("target_max") is not None:
        ok.append(v <= r["target_max"])
    return "-" if not ok else ("met" if all(ok) else "NOT met")


def _fmt(x: Any) -> str:
    if x is None:
        return "-"
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}"


def table(rows: list[Row]) -> str:
    """The results as a Markdown table."""
    out = ["| figure | value | unit | baseline (same run) | ratio | target |",
           "|---|---:|---|---|---:|---|"]
    for r in rows:
        b = r.get("baseline")
        base = f"{r.get('baseline_name', '')}: {_fmt(b)}" if b is not None else "-"
        ratio = f"{r['value'] / b:.1f}x" if r.get("value") and b else "-"
        out.append(f"| {r['name']} | {_fmt(r.get('value'))} | {r.get('unit', '')} | {base} | "
                   f"{ratio} | {_verdict(r)} |")
    return "\n".join(out)


BEGIN, END = "<!-- bench table: begin -->", "<!-- bench table: end -->"


def readme_block(result: dict[str, Any]) -> str:
    """The README's Performance block: the machine, the table and every row's note."""
    m = result["machine"]
    load = m.get("load_avg")
    head = (f"Measured {m['date'][:10]} on {m['cpu']}, {m['cores']} cores, Python {m['python']}, "
            f"numpy {m['numpy']}, numba {m['numba']}, scipy {m['scipy']}, rosbags {m['rosbags']}"
            + (f"; load average {load[0]:.1f} at the end (the graph rows' own)" if load else "")
            + f"; `make bench` took {result['wall_s'] / 60:.1f} min:")
    notes = [f"- *{r['name']}*: {r['note']}" for r in result["rows"] if r.get("note")]
    return "\n\n".join([head, table(result["rows"]), "Notes of the same run:\n" + "\n".join(notes)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="dcsms_ros benchmarks")
    ap.add_argument("--smoke", action="store_true", help="tiny sizes, a few seconds")
    ap.add_argument("--only", nargs="*", choices=sorted(REGISTRY), help="run only these")
    ap.add_argument("--out", type=Path, default=HERE / "results.json")
    ap.add_argument("--rt-seconds", type=float, default=None, metavar="S",
                    help="real-time graph run length (default 60 s; smoke 3 s)")
    ap.add_argument("--readme", type=Path, default=None, metavar="FILE",
                    help="write the table of --out (no benchmark run) into FILE's bench block")
    a = ap.parse_args(argv)
    if a.readme is not None:
        from dcsms_ros.errors import DcsmsError
        from dcsms_ros.markers import replace_between_markers

        try:
            replace_between_markers(a.readme, readme_block(json.loads(a.out.read_text())),
                                    BEGIN, END)
        except (DcsmsError, OSError, ValueError) as exc:
            print(f"bench: error: {exc}", file=sys.stderr)
            return 2
        print(f"updated {a.readme} from {a.out}")
        return 0
    benches: dict[str, Callable[[bool, Path], list[Row]]] = {
        **REGISTRY, "graph": functools.partial(_graph, rt_seconds=a.rt_seconds)}
    rows: list[Row] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dcsms-bench-") as tmp:
        for name, fn in benches.items():
            if a.only and name not in a.only:
                continue
            t = time.perf_counter()
            for r in fn(a.smoke, Path(tmp)):
                r["bench"] = name
                r["verdict"] = _verdict(r)
                rows.append(r)
            print(f"[{name}: {time.perf_counter() - t:.1f} s]", file=sys.stderr, flush=True)
    result = {"machine": machine(), "smoke": a.smoke, "wall_s": time.perf_counter() - t0,
              "rows": rows}
    a.out.write_text(json.dumps(result, indent=1) + "\n")
    m = result["machine"]
    print(f"{m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}, "
          f"numba {m['numba']}, {m['date']}")
    print(table(rows))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
