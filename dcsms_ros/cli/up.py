"""``dcsms up``: start the ROS 2 graph, one process per node, show status, stop cleanly.

Each node runs as ``python -m dcsms_ros.nodes.<executable> --ros-args ...`` with one generated
params file: the validated configuration (``--config`` plus every ``--set``) for ``/**`` and
the per-node settings (schedule, initial enable state, duration, ...) under each node's full
name. Ctrl-C or SIGTERM: every node gets SIGINT, then SIGTERM and SIGKILL after a timeout;
exit status 0 and no traceback. Node logs go to files in ``--log-dir`` (shown at start) unless
``--verbose``.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dcsms_ros.cli.common import add_config_options, load_cfg
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import Mode, controller_ids, enabled_controllers, parse_mode
from dcsms_ros.errors import DcsmsError

#: Seconds a node gets to exit after SIGINT, then after SIGTERM, before SIGKILL.
STOP_TIMEOUTS = (5.0, 2.0)


@dataclass
class Child:
    """One node process."""

    name: str
    argv: list[str]
    log: Path | None = None
    proc: subprocess.Popen | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    env: dict[str, str] = field(default_factory=dict)


#: The per-sample control path: the processes ``--rt-priority`` puts under SCHED_FIFO.
CONTROL_PATH = ("plant_simulator", "sensor_decoupling", "fb_", "ff_", "excitation")


def set_rt_priority(kids: list[Child], priority: int) -> None:
    """``--rt-priority``: SCHED_FIFO at ``priority`` (1-99) for the control-path processes;
    mode_switch, the recorder and observers keep the default scheduler."""
    from dcsms_ros.nodes.runtime import RT_PRIORITY_ENV

    for kid in kids:
        if kid.name.startswith(CONTROL_PATH):
            kid.env[RT_PRIORITY_ENV] = str(priority)


def stream_topics(n: int, excitation: bool = False) -> list[str]:
    """Every per-sample topic of an ``n``-stage graph (for observers that must not miss one)."""
    bodies = topics.body_names(n)
    return ([topics.SENSORS_RAW, topics.ACTUATORS_APPLIED]
            + [topics.velocity_topic(b) for b in bodies] + [topics.truth_topic(b) for b in bodies]
            + [topics.force_topic(c) for c in controller_ids(n)]
            + ([topics.EXCITATION] if excitation else []))


def params_document(cfg: SystemConfig, schedule: str, mode: Mode, duration_s: float,
                    observers: list[str], ground_from: str = "",
                    excite: list[str] | None = None,
                    excite_active: bool = True) -> dict[str, Any]:
    """The params file of one run: shared configuration plus per-node settings; ``excite``
    (``--excite`` specifications) adds the excitation node, active from the start or not."""
    n = cfg.plant.num_stages
    # empty arrays have no type in a params file; the nodes default them to empty anyway
    flat = {k: v for k, v in (cfg.params or {}).items() if not (isinstance(v, list) and not v)}
    flat["schedule"] = schedule
    if observers:  # every node with a stream publisher holds its first lockstep answer
        flat["wait_for_subscribers"] = list(observers)
    doc: dict[str, Any] = {"/**": {"ros__parameters": flat}}
    on = enabled_controllers(mode, n)
    per_node: dict[str, dict[str, Any]] = {
        "plant_simulator": {"duration_s": float(duration_s), "ground_from": ground_from},
        "sensor_decoupling": {"use_sim_time": True},
        # no /clock for mode_switch: its timers are steady and its trip is stamped with the
        # judged sample; waking its multi-threaded executor at 100 Hz cost ~14 % of a core
        "mode_switch": {"initial_mode": mode.value, "use_sim_time": False},
    }
    for cid in controller_ids(n):
        p: dict[str, Any] = {"enabled": cid in on, "use_sim_time": True}
        if cid.startswith("fb_"):
            p["stage"] = int(cid.rsplit("stage", 1)[1])
        per_node[cid] = p
    if excite:
        per_node["plant_simulator"]["excitation"] = True
        per_node[topics.EXCITATION_ID] = {"spec": list(excite), "active": excite_active,
                                          "duration_s": float(duration_s),
                                          "use_sim_time": True}
    for name, p in per_node.items():
        doc[f"{topics.NAMESPACE}/{name}"] = {"ros__parameters": p}
    return doc


def graph_children(n: int, params_file: Path, excitation: bool = False) -> list[Child]:
    """The node processes of an ``n``-stage graph (argv only, not started), with the
    excitation node when asked."""
    def argv(executable: str, name: str) -> list[str]:
        return [sys.executable, "-m", f"dcsms_ros.nodes.{executable}", "--ros-args",
                "-r", f"__node:={name}", "-r", f"__ns:={topics.NAMESPACE}",
                "--params-file", str(params_file)]

    kids = [Child("mode_switch", argv("mode_switch", "mode_switch"))]
    kids += [Child(c, argv("feedback_controller" if c.startswith("fb_") else
                           "feedforward_controller", c)) for c in controller_ids(n)]
    kids.append(Child("sensor_decoupling", argv("sensor_decoupling", "sensor_decoupling")))
    if excitation:
        kids.append(Child(topics.EXCITATION_ID, argv("excitation", topics.EXCITATION_ID)))
    kids.append(Child("plant_simulator", argv("plant_simulator", "plant_simulator")))
    return kids


def child_env() -> dict[str, str]:
    """Environment of the node processes: localhost discovery, unbuffered, plain logs."""
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env["PYTHONUNBUFFERED"] = "1"
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    return env


def start(kids: list[Child], log_dir: Path, verbose: bool) -> None:
    """Start every child in its own session (the terminal's Ctrl-C reaches only ``up``)."""
    env = child_env()
    for kid in kids:
        out: Any = None
        if not verbose:
            kid.log = log_dir / f"{kid.name}.log"
            out = kid.log.open("wb")
        kid.proc = subprocess.Popen(kid.argv, stdout=out, stderr=subprocess.STDOUT if out else
                                    None, stdin=subprocess.DEVNULL, env={**env, **kid.env},
                                    start_new_session=True)
        if out is not None:
            out.close()


def stop(kids: list[Child]) -> None:
    """SIGINT to every running child, then SIGTERM, then SIGKILL after the timeouts."""
    for sig, timeout in ((signal.SIGINT, STOP_TIMEOUTS[0]), (signal.SIGTERM, STOP_TIMEOUTS[1]),
                         (signal.SIGKILL, 5.0)):
        alive = [k for k in kids if k.proc is not None and k.proc.poll() is None]
        if not alive:
            return
        for k in alive:
            try:
                k.proc.send_signal(sig)  # type: ignore[union-attr]
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + timeout
        for k in alive:
            try:
                k.proc.wait(max(deadline - time.monotonic(), 0.0))  # type: ignore[union-attr]
            except subprocess.TimeoutExpired:
                pass


def register(subparsers: Any) -> None:
    """Add the ``up`` sub-command."""
    p = subparsers.add_parser(
        "up", help="start the ROS 2 node graph",
        description="Start the plant simulator, sensor decoupling, controllers and mode switch, "
        "each as its own process; show status until Ctrl-C/SIGTERM (or --duration).")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--lockstep", dest="schedule", action="store_const", const="lockstep",
                   help="deterministic: the plant waits for every controller each sample "
                   "(identical to `dcsms sim`)")
    g.add_argument("--realtime", dest="schedule", action="store_const", const="realtime",
                   help="the plant steps on the wall clock at plant.rate_hz (default)")
    p.set_defaults(schedule="realtime")
    p.add_argument("--mode", default="passive", metavar="NAME",
                   help="initial mode: Passive, FBC, FFC, FBC+FFC, DFBC, DFBC+FFC")
    add_config_options(p)
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds of simulated time (default: until Ctrl-C)")
    p.add_argument("--record", type=Path, default=None, metavar="OUT",
                   help="record every /dcsms topic into the bag directory OUT")
    p.add_argument("--record-topics", nargs="+", default=None, metavar="TOPIC",
                   help="with --record: only these topics (e.g. the analysis set "
                   "/dcsms/velocity/* /dcsms/actuators/applied /dcsms/mode /dcsms/config)")
    p.add_argument("--ground-from", default="", metavar="BAG[:TOPIC]",
                   help="replay a recorded ground velocity (TwistStamped, resampled to the "
                   "control rate) instead of white noise")
    p.add_argument("--excite", action="append", default=[], metavar="SPEC",
                   help="add the excitation node (as `dcsms sim --excite`, repeatable): the "
                   "plant sums /dcsms/force/excitation with the controllers' forces; active "
                   "from the start unless --excite-off; /dcsms/excitation/enable starts and "
                   "stops it")
    p.add_argument("--excite-off", action="store_true",
                   help="with --excite: start the excitation inactive")
    p.add_argument("--wait-for-subscribers", nargs="+", default=[], metavar="TOPIC",
                   help="before the first sample, wait for a subscriber outside the graph on "
                   "each TOPIC (e.g. a probe)")
    p.add_argument("--connect-timeout", type=float, default=30.0, metavar="S",
                   help="give up if the graph is not connected after S seconds (default 30)")
    p.add_argument("--log-dir", type=Path, default=None, metavar="DIR",
                   help="where the node logs go (default: a new directory under /tmp)")
    p.add_argument("--rt-priority", type=int, default=0, metavar="N",
                   help="run the control path (plant, decoupling, controllers) under SCHED_FIFO "
                   "priority N (1-99; needs root or CAP_SYS_NICE; 0: default scheduler)")
    p.add_argument("--verbose", action="store_true", help="show the nodes' output here")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler: start, wait for the graph, show status, stop; 0 after a clean stop."""
    mode = parse_mode(args.mode)
    cfg = load_cfg(args)
    if args.duration is not None and not args.duration > 0:
        raise DcsmsError(f"--duration {args.duration}: must be > 0")
    if not 0 <= args.rt_priority <= 99:
        raise DcsmsError(f"--rt-priority {args.rt_priority}: must be 0 (off) or 1..99")
    if args.record is not None and args.record.exists():
        raise DcsmsError(f"--record {args.record}: exists already, not overwriting")
    if args.ground_from:  # fail here with one line, not later inside the plant process
        from dcsms_ros.analysis.replay import load_ground, parse_ground_spec

        bag, topic = parse_ground_spec(args.ground_from)
        load_ground(bag, topic, cfg.plant.rate_hz, cfg.plant.dof)
    if args.excite:  # one line here, not inside the node process
        from dcsms_ros.cli.sim import parse_excitations

        parse_excitations(cfg, args.excite)
    elif args.excite_off:
        raise DcsmsError("--excite-off needs --excite SPEC")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix="dcsms-up-"))
    log_dir.mkdir(parents=True, exist_ok=True)
    n = cfg.plant.num_stages
    observers = list(args.wait_for_subscribers)
    kids: list[Child] = []
    if args.record is not None:
        from dcsms_ros.cli.record import recorder_command  # the recorder is optional

        kids.append(Child("recorder", recorder_command(args.record, args.record_topics)))
        if args.schedule == "lockstep":  # lockstep must not outrun the recorder's start
            streams = stream_topics(n, bool(args.excite))
            observers += [t for t in streams if not args.record_topics
                          or t in args.record_topics]
    params_file = log_dir / "params.yaml"
    params_file.write_text(yaml.safe_dump(params_document(
        cfg, args.schedule, mode, args.duration or 0.0, observers, args.ground_from,
        args.excite, not args.excite_off), sort_keys=False))
    graph = graph_children(n, params_file, bool(args.excite))
    if args.rt_priority:
        set_rt_priority(graph, args.rt_priority)
    stop_flag = {"signal": 0}

    def on_signal(signum: int, frame: Any) -> None:
        stop_flag["signal"] = signum

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    from dcsms_ros.nodes.monitor import GraphMonitor  # rclpy only when needed

    status = 0
    monitor = None
    try:
        start(kids, log_dir, args.verbose)  # recorder first: it must see the first samples
        start(graph, log_dir, args.verbose)
        print(f"dcsms up: {args.schedule}, mode {mode.label}, config {cfg.source}, "
              f"{len(graph)} nodes, logs in {log_dir}", flush=True)
        monitor = GraphMonitor(n)
        status = monitor.supervise(graph + kids, lambda: stop_flag["signal"] != 0,
                                   args.connect_timeout, args.duration is not None)
    finally:
        if monitor is not None:
            monitor.close()
        stop(graph)  # the graph first, so the recorder receives everything it published
        stop(kids)
        for s, h in old.items():
            signal.signal(s, h)
    if kids and kids[0].proc is not None and kids[0].proc.returncode not in (0, None):
        print(f"dcsms up: the recorder exited with status {kids[0].proc.returncode}",
              file=sys.stderr)
        status = status or 1
    print("dcsms up: stopped", flush=True)
    return status


__all__ = ["graph_children", "params_document", "register", "run", "stream_topics"]
