"""Start a graph (:class:`~dcsms_ros.graph.GraphSpec`), supervise it, stop it cleanly.

Two deployments of the same nodes:

* **one process per node** (the ``ros2 run`` deployment, ``dcsms up``'s default): each node
  runs as ``python -m dcsms_ros.nodes.<executable> --ros-args -r __node:=<name> -r
  __ns:=<namespace> --params-file <file>``;
* **composed** (``--composed``): every node in one process
  (:mod:`dcsms_ros.nodes.container`), on one rclpy context, the per-sample cycle run by one
  driver thread.

Both read one params file (:meth:`GraphSpec.params_document`). A recorder (``--record``) runs as
its own process, or inside the composed process (``recorder="composed"``, the default: it takes
the messages from the process's bus, every one, without DDS). Stop: the graph's processes one at
a time (:func:`~.processes.stop_in_turn`), then the recorder, so it receives everything the graph
published. Node logs go to files in ``log_dir`` unless ``verbose``; how the processes are
started and stopped is :mod:`.processes`.
"""

from __future__ import annotations

import fnmatch
import json
import sys
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from dcsms_ros.analysis.gaps import read_published
from dcsms_ros.cli.hoststeal import read_cpu_times, steal_fraction
from dcsms_ros.cli.parts import RECORDER_PART, merge_parts, parts_dir, records_in_nodes
from dcsms_ros.cli.processes import (
    RECORDER_STOP_TIMEOUTS,
    STOP_TIMEOUTS,
    Child,
    adopting_orphans,
    reap_orphans,
    report_exits,
    start,
    stop,
    stop_in_turn,
)
from dcsms_ros.core.modes import Mode
from dcsms_ros.errors import BagError
from dcsms_ros.graph import (
    LOCKSTEP_WRITER_DEPTH,
    RECORD_PART_ENV,
    RECORD_TOPICS_ENV,
    RT_CPUS_ENV,
    RT_PRIORITY_ENV,
    GraphSpec,
    format_cpus,
)
from dcsms_ros.jsonutil import jsonable
from dcsms_ros.protocols.runstats import RunSummary, summarize

RECORDERS = ("process", "composed")
#: Niceness of a recorder process beside a real-time graph: the observer yields the CPU to the
#: control path's threads under the normal scheduler (its DDS reception above all, which is what
#: delivers a sample to a SCHED_FIFO hot thread). 5 alternating pairs of 20 s per-process runs:
#: stale forces 50-693 against 671-5,164 at 0, every pair lower, the bag as complete
#: (docs/performance.md). Lockstep waits for its recorder, so there it keeps the parent's.
RECORDER_NICE = 10


def node_argv(spec: GraphSpec, name: str, params_file: Path) -> list[str]:
    """Command line of node ``name`` as its own process."""
    n = spec.node(name)
    remap = [a for f, t in n.remappings for a in ("-r", f"{f}:={t}")]
    return [sys.executable, "-m", n.module, "--ros-args", "-r", f"__node:={n.name}",
            "-r", f"__ns:={spec.namespace}", "--params-file", str(params_file), *remap]


def children(spec: GraphSpec, params_file: Path, rt_priority: int = 0,
             rt_cpus: Collection[int] = ()) -> list[Child]:
    """One process per node (argv only, not started), in the spec's start order;
    ``rt_priority`` (1-99) puts the control-path nodes' hot threads under SCHED_FIFO and
    ``rt_cpus`` on those CPUs."""
    kids = []
    for n in spec.nodes:
        kid = Child(n.name, node_argv(spec, n.name, params_file))
        if rt_priority and n.control_path:
            kid.env[RT_PRIORITY_ENV] = str(rt_priority)
        if rt_cpus and n.control_path:
            kid.env[RT_CPUS_ENV] = format_cpus(rt_cpus)
        kids.append(kid)
    return kids


def composed_child(graph_file: Path, params_file: Path, rt_priority: int = 0,
                   record: Sequence[str] = (), rt_cpus: Collection[int] = ()) -> Child:
    """The composed process: every node of ``graph_file`` in one process (``record``: the
    recorder's ``OUT [TOPIC ...]`` to run inside it too; ``rt_cpus``: its driver's CPUs)."""
    argv = [sys.executable, "-m", "dcsms_ros.nodes.container", "--graph", str(graph_file),
            "--params-file", str(params_file), "--rt-priority", str(rt_priority)]
    if record:
        argv += ["--record", *record]
    kid = Child("graph", argv)
    if rt_cpus:
        kid.env[RT_CPUS_ENV] = format_cpus(rt_cpus)
    return kid


def recorder_command(out: str | Path, topics: Sequence[str] | None = None,
                     storage: str = "mcap", duration_s: float | None = None,
                     exclude: Sequence[str] = ()) -> list[str]:
    """The argv that runs ``dcsms record`` as a child process with this interpreter.

    Start it with ``subprocess.Popen`` before the graph's publishers, stop it with
    ``proc.send_signal(signal.SIGINT)`` (or SIGTERM) and ``proc.wait()``: exit 0 means the bag
    is complete; the report is on the child's stdout.
    """
    cmd = [sys.executable, "-m", "dcsms_ros.cli", "record", str(out), "--storage", storage]
    if topics:
        cmd += ["--topics", *topics]
    if exclude:
        cmd += ["--exclude", *exclude]
    if duration_s is not None:
        cmd += ["--duration", repr(float(duration_s))]
    return cmd


@dataclass
class Deployment:
    """How to run a graph; see :func:`run_graph`."""

    composed: bool = False
    rt_priority: int = 0
    rt_cpus: frozenset[int] = frozenset()
    record: Path | None = None
    record_topics: Sequence[str] | None = None
    recorder: str = "composed"
    log_dir: Path = Path("/tmp")
    verbose: bool = False
    connect_timeout: float = 30.0
    expect_finish: bool = False
    events: Sequence[tuple[float, Mode]] = ()


def write_files(spec: GraphSpec, log_dir: Path) -> tuple[Path, Path]:
    """The run's params file and (for the composed process) the graph file, in ``log_dir``."""
    params_file = log_dir / "params.yaml"
    params_file.write_text(yaml.safe_dump(spec.params_document(), sort_keys=False))
    graph_file = log_dir / "graph.yaml"
    graph_file.write_text(yaml.safe_dump(spec.to_dict(), sort_keys=False))
    return params_file, graph_file


def run_graph(spec: GraphSpec, how: Deployment, stop_requested: Callable[[], bool],
              rate_hz: float, announce: Callable[[int], None] = lambda n: None) -> int:
    """Start ``spec``, supervise it until ``stop_requested()`` or the plant finished, stop.

    Returns 0 after a clean stop or finish, 1 if a process died, the graph did not connect or
    the recorder failed. ``announce(number of processes)`` is called once they started.
    """
    # deferred: the monitor is an rclpy node, and the CLI imports this module (Deployment,
    # RECORDERS) to build its parser, which `dcsms --help` must not pay for
    from dcsms_ros.cli.monitor import monitoring  # noqa: PLC0415

    how.log_dir.mkdir(parents=True, exist_ok=True)
    params_file, graph_file = write_files(spec, how.log_dir)
    kids: list[Child] = []
    in_process: list[str] = []
    parts: Path | None = None
    streams: list[str] = []
    recorded_streams: list[str] = []
    if how.record is not None:
        topics = list(how.record_topics or [f"{spec.namespace.rstrip('/')}/*", "/diagnostics"])
        recorded_streams = [t for t in spec.stream_topics()
                            if any(fnmatch.fnmatchcase(t, pat) for pat in topics)]
        if how.composed and how.recorder == "composed":
            in_process = [str(how.record), *topics]
        else:
            out = how.record
            if records_in_nodes(how.composed, how.recorder):
                parts = parts_dir(how.record)
                if parts.exists():
                    raise BagError(f"{parts}: a previous run's parts are in the way; remove it")
                streams = recorded_streams
                out = parts / RECORDER_PART
            # lockstep: the reader history covers as much as the writers' (qos.py)
            depth = ["--queue-depth", str(LOCKSTEP_WRITER_DEPTH)] \
                if spec.schedule == "lockstep" else []
            nice = RECORDER_NICE if spec.schedule != "lockstep" else 0
            kids.append(Child("recorder", recorder_command(out, topics, exclude=streams)
                              + depth, nice=nice))
    if how.composed:
        graph = [composed_child(graph_file, params_file, how.rt_priority, in_process,
                                how.rt_cpus)]
    else:
        graph = children(spec, params_file, how.rt_priority, how.rt_cpus)
        if parts is not None:
            for kid in graph:
                kid.env[RECORD_PART_ENV] = str(parts / kid.name)
                kid.env[RECORD_TOPICS_ENV] = " ".join(streams)
    status = 0
    plant: dict[str, str] = {}
    steal: float | None = None
    cpu0 = read_cpu_times()
    # a composed process that dies leaves its bag writer closing the bag: waited for below
    with adopting_orphans():
        try:
            start(kids, how.log_dir, how.verbose)  # recorder first: it must see the first samples
            start(graph, how.log_dir, how.verbose)
            announce(len(graph))
            # the monitor's node and context go before the graph is stopped
            with monitoring(spec, how.events, rate_hz) as monitor:
                status = monitor.supervise(graph + kids, stop_requested, how.connect_timeout,
                                           how.expect_finish)
                plant = dict(monitor.diag.get("plant_simulator", {}))
                steal = steal_fraction(cpu0, read_cpu_times())
        finally:
            # the graph first (composed with the recorder inside: its drain too), so the
            # recorder receives everything it published
            stop_in_turn(graph, RECORDER_STOP_TIMEOUTS if in_process or parts else STOP_TIMEOUTS)
            stop(kids, RECORDER_STOP_TIMEOUTS)
            orphans = reap_orphans(graph + kids)
    status = report_exits(graph + kids, orphans) or status
    if parts is not None and how.record is not None:
        status = merge_parts(parts, how.record) or status
    if plant:
        report_summary(spec, plant, how.record, how.log_dir, how.composed, recorded_streams,
                       steal)
    return status


def report_summary(spec: GraphSpec, plant: dict[str, str], bag: Path | None,
                   log_dir: Path, composed: bool = False,
                   streams: Sequence[str] | None = None,
                   steal: float | None = None) -> RunSummary:
    """Print the run's summary line (and a warning, whose hint depends on ``composed``) and
    write it as ``summary.json`` in ``log_dir``. ``streams``: the per-sample topics that were
    to be recorded (default every one of ``spec``); one the bag lacks counts as none recorded.
    ``steal``: the machine's steal time while the graph ran (:mod:`.hoststeal`)."""
    counts = bag_counts(bag) if bag is not None else None
    published = bag_published(bag) if bag is not None else None
    summary = summarize(plant, counts, list(spec.stream_topics() if streams is None
                                            else streams), published, steal)
    print(f"dcsms up: summary: {summary.line()}", flush=True)
    warning = summary.warning(composed)
    if warning:
        print(f"dcsms up: warning: {warning}", file=sys.stderr, flush=True)
    (log_dir / "summary.json").write_text(json.dumps(jsonable(summary.to_dict()), indent=1,
                                                     allow_nan=False) + "\n")
    return summary


def _bag_info(bag: Path) -> dict[str, Any]:
    """The closed bag's ``metadata.yaml`` information (empty if it has none)."""
    try:
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    except (OSError, yaml.YAMLError):
        return {}
    info = meta.get("rosbag2_bagfile_information", {}) if isinstance(meta, dict) else {}
    return info if isinstance(info, dict) else {}


def bag_counts(bag: Path) -> dict[str, int]:
    """Messages per topic in the closed bag's ``metadata.yaml`` (empty if it has none)."""
    return {t["topic_metadata"]["name"]: int(t["message_count"])
            for t in _bag_info(bag).get("topics_with_message_count", [])}


def bag_published(bag: Path) -> dict[str, int]:
    """Messages per topic its publisher published, as the recorder left them in the bag's
    ``custom_data`` (:data:`~dcsms_ros.analysis.gaps.PUBLISHED_KEY`; empty if unknown)."""
    return read_published(_bag_info(bag).get("custom_data"))


__all__ = ["RECORDERS", "Deployment", "bag_counts", "bag_published", "children",
           "composed_child", "node_argv", "recorder_command", "report_summary", "run_graph",
           "write_files"]
