"""``dcsms up``: start the ROS 2 graph, show status, stop cleanly.

The graph is :func:`dcsms_ros.graph.define_graph` of the configuration (``--config`` plus every
``--set``), in namespace ``--namespace``; it runs one process per node (the ``ros2 run``
deployment, default) or ``--composed`` (every node in one process, one driver thread for the
per-sample cycle); :mod:`dcsms_ros.cli.deploy` starts and stops it. Ctrl-C, SIGTERM or SIGHUP
(the terminal closed; :mod:`dcsms_ros.stopsignals`): every process gets SIGINT, then SIGTERM,
SIGABRT (its threads' stacks into its log) and SIGKILL after timeouts; exit status 0 and no
traceback.
Node logs go to files in ``--log-dir`` (shown at start) unless ``--verbose``.
"""

from __future__ import annotations

import argparse
import os
import signal
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import (
    add_config_options,
    load_cfg,
    parse_excitations,
    parse_schedule,
    print_model_check,
    refuse_unstable_start,
)
from dcsms_ros.cli.deploy import RECORDERS, Deployment, run_graph
from dcsms_ros.cli.parts import records_in_nodes
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.errors import DcsmsError
from dcsms_ros.graph import GraphSpec, define_graph, format_cpus, parse_cpus
from dcsms_ros.stopsignals import STOP_SIGNALS, StopFlag


def add_deploy_options(p: argparse.ArgumentParser, composed: bool = False) -> None:
    """``--namespace``, ``--composed``, ``--recorder``, ``--rt-priority``, ``--rt-cpus`` (up,
    sim, demo);
    with ``composed`` (the demo, which is about results), composed is the default and
    ``--per-process`` the option."""
    p.add_argument("--namespace", default=topics.NAMESPACE, metavar="NS",
                   help=f"namespace of every topic and service of the graph (default "
                   f"{topics.NAMESPACE}); two tables run side by side under two namespaces")
    if composed:
        p.add_argument("--composed", action="store_true",
                       help="every node in one process (the default here)")
        p.add_argument("--per-process", dest="composed", action="store_false",
                       help="one process per node, as `ros2 run` (default: every node in one "
                       "process, one driver thread, messages handed over in the process)")
        p.set_defaults(composed=True)
    else:
        p.add_argument("--composed", action="store_true",
                       help="every node in one process, one driver thread for the sample "
                       "cycle (default: one process per node, as `ros2 run`)")
    p.add_argument("--recorder", choices=RECORDERS, default=None,
                   help="with a recording: 'composed' (default) records each per-sample topic in "
                   "the process that publishes it, without DDS (composed: the one process; "
                   "lockstep ~1.6x faster, real-time control latency p99 0.19-0.27 ms; one "
                   "process per node: each node process writes a part, merged into the bag at "
                   "the end), the other topics in a recorder process; 'process' records "
                   "everything in a recorder process over DDS (docs/performance.md)")
    p.add_argument("--rt-priority", type=int, default=0, metavar="N",
                   help="run the hot thread of each control-path process (plant, decoupling, "
                   "controllers; composed: the driver thread, with the executor's thread on "
                   "its core so that it never holds the GIL while the driver computes) under "
                   "SCHED_FIFO priority N (1-99; needs root or CAP_SYS_NICE; 0: default "
                   "scheduler)")
    p.add_argument("--rt-cpus", default="", metavar="LIST",
                   help="run those hot threads on these CPUs only (a list as taskset -c takes "
                   "it: 1, 0,2-3; default: the kernel places them). On 2 cores, all on one: a "
                   "controller's CPU a sample 8-27 %% lower, samples later "
                   "(docs/performance.md)")
    p.add_argument("--allow-unstable", action="store_true",
                   help="let mode switches and tunings the model calls unstable through (the "
                   "instability trip is the last line of defence)")
    p.add_argument("--no-supervisor", action="append_const", dest="overrides",
                   const="supervisor.enabled=false",
                   help="no supervisor: any instability trip latches Passive until reset_trip "
                   "(same as --set supervisor.enabled=false; docs/reliability.md)")


def check_deploy_options(args: argparse.Namespace) -> str:
    """Validate the deployment options of a run (``args.rt_cpus`` becomes a set of CPUs);
    returns the namespace (absolute)."""
    if not 0 <= args.rt_priority <= 99:
        raise DcsmsError(f"--rt-priority {args.rt_priority}: must be 0 (off) or 1..99")
    try:
        cpus = parse_cpus(args.rt_cpus) if isinstance(args.rt_cpus, str) else args.rt_cpus
    except ValueError as exc:
        raise DcsmsError(f"--rt-cpus {exc}") from None
    usable = os.sched_getaffinity(0)
    if not cpus <= usable:
        raise DcsmsError(f"--rt-cpus {format_cpus(cpus)}: this process may use CPUs "
                         f"{format_cpus(usable)} only")
    args.rt_cpus = cpus
    return topics.check_namespace(args.namespace)


def register(subparsers: Any) -> None:
    """Add the ``up`` sub-command."""
    p = subparsers.add_parser(
        "up", help="start the ROS 2 node graph",
        description="Start the plant simulator, sensor decoupling, controllers and mode switch "
        "(one process each, or --composed in one); show status until Ctrl-C/SIGTERM (or "
        "--duration).")
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
    p.add_argument("--schedule", dest="switches", default="", metavar="T:MODE,...",
                   help='mode switches at simulated times, e.g. "12:fbc,24:dfbc" (through the '
                   "set_mode services; lockstep: on the sample round(T * rate))")
    p.add_argument("--record", type=Path, default=None, metavar="OUT",
                   help="record every topic of the graph and /diagnostics into bag OUT")
    p.add_argument("--record-topics", nargs="+", default=None, metavar="TOPIC",
                   help="with --record: only these topics (e.g. the analysis set "
                   "/dcsms/velocity/* /dcsms/actuators/applied /dcsms/mode /dcsms/config)")
    p.add_argument("--ground-from", default="", metavar="BAG[:TOPIC]",
                   help="replay a recorded ground velocity (TwistStamped, resampled to the "
                   "control rate) instead of white noise")
    p.add_argument("--excite", action="append", default=[], metavar="SPEC",
                   help="add the excitation node (as `dcsms sim --excite`, repeatable): the "
                   "plant sums <namespace>/force/excitation with the controllers' forces; "
                   "active from the start unless --excite-off; <namespace>/excitation/enable "
                   "starts and stops it")
    p.add_argument("--excite-off", action="store_true",
                   help="with --excite: start the excitation inactive")
    p.add_argument("--wait-for-subscribers", nargs="+", default=[], metavar="TOPIC",
                   help="before the first sample, wait for a subscriber outside the graph on "
                   "each TOPIC (e.g. a probe)")
    p.add_argument("--connect-timeout", type=float, default=30.0, metavar="S",
                   help="give up if the graph is not connected after S seconds (default 30)")
    p.add_argument("--log-dir", type=Path, default=None, metavar="DIR",
                   help="where the node logs go (default: a new directory under /tmp)")
    add_deploy_options(p)
    p.add_argument("--verbose", action="store_true", help="show the nodes' output here")
    p.set_defaults(func=run)


def build_graph(cfg: SystemConfig, args: argparse.Namespace, schedule: str, mode: Mode,
                duration_s: float, events: Sequence[tuple[float, Mode]],
                observers: Sequence[str] = ()) -> GraphSpec:
    """The graph of a run from the common options (namespace, allow-unstable, ground).

    A run with a duration waits for this process's readers of ``plant/finished`` and
    ``/diagnostics`` too: a short run could otherwise end before the supervisor hears the plant
    say it finished (and its last report).
    """
    if events and schedule == "lockstep" and events[0][0] * cfg.plant.rate_hz < 0.5:
        raise DcsmsError("--schedule: a switch at t=0 is the initial mode; use --mode")
    if duration_s > 0:
        finished = topics.Names(topics.check_namespace(args.namespace)).plant_finished
        observers = [*observers, finished, topics.DIAGNOSTICS]
    return define_graph(cfg, schedule=schedule, mode=mode, namespace=args.namespace,
                        duration_s=duration_s, observers=observers,
                        ground_from=getattr(args, "ground_from", "") or "",
                        allow_unstable=args.allow_unstable,
                        hold_at_s=events[0][0] if events and schedule == "lockstep" else 0.0,
                        excite=getattr(args, "excite", ()) or (),
                        excite_active=not getattr(args, "excite_off", False))


def launch(spec: GraphSpec, args: argparse.Namespace, events: Sequence[tuple[float, Mode]],
           record: Path | None, record_topics: Sequence[str] | None, log_dir: Path | None,
           expect_finish: bool, rate_hz: float, verbose: bool = False,
           interrupted_status: int | None = None) -> int:
    """Run ``spec`` with the deployment options of ``args`` until a signal or its end.

    Returns the graph's status (0 after a clean stop or finish); ``interrupted_status``, when
    given, instead of 0 when a signal stopped the run (a run that must finish, such as the
    demo's, is then incomplete and must not be analysed as if it were whole)."""
    log_dir = log_dir or Path(tempfile.mkdtemp(prefix="dcsms-up-"))
    how = Deployment(composed=args.composed, rt_priority=args.rt_priority,
                     rt_cpus=args.rt_cpus, record=record,
                     record_topics=record_topics, recorder=args.recorder or "composed",
                     log_dir=log_dir,
                     verbose=verbose, connect_timeout=getattr(args, "connect_timeout", 60.0),
                     expect_finish=expect_finish, events=events)

    stop = StopFlag()
    old = {s: signal.signal(s, stop) for s in STOP_SIGNALS}
    try:
        status = run_graph(spec, how, lambda: bool(stop), rate_hz,
                           announce=lambda k: print(
                               f"dcsms up: {spec.schedule}, "
                               f"{'composed, ' if args.composed else ''}{k} "
                               f"process{'es' if k > 1 else ''}, namespace {spec.namespace}, "
                               f"logs in {log_dir}", flush=True))
        if status == 0 and stop and interrupted_status is not None:
            return interrupted_status
        return status
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def run(args: argparse.Namespace) -> int:
    """Handler: start, wait for the graph, show status, stop; 0 after a clean stop."""
    mode = parse_mode(args.mode)
    cfg = load_cfg(args)
    events = parse_schedule(args.switches)
    check_deploy_options(args)
    if args.duration is not None and not args.duration > 0:
        raise DcsmsError(f"--duration {args.duration}: must be > 0")
    if args.record is not None and args.record.exists():
        raise DcsmsError(f"--record {args.record}: exists already, not overwriting")
    if args.ground_from:  # fail here with one line, not later inside the plant process
        from dcsms_ros.analysis.replay import (  # noqa: PLC0415 - deferred for --help
            load_ground,
            parse_ground_spec,
        )

        bag, topic = parse_ground_spec(args.ground_from)
        load_ground(bag, topic, cfg.plant.rate_hz, cfg.plant.dof)
    if args.excite:  # one line here, not inside the node process
        parse_excitations(cfg, args.excite)
    elif args.excite_off:
        raise DcsmsError("--excite-off needs --excite SPEC")
    print_model_check(cfg)
    refuse_unstable_start(cfg, mode, args.allow_unstable, args.schedule == "realtime")
    observers = list(args.wait_for_subscribers)
    spec = build_graph(cfg, args, args.schedule, mode, args.duration or 0.0, events)
    if args.record is not None:
        # the run starts once the recorder listens: its bag holds every sample from 0
        observers += spec.recorded_observed(
            args.record_topics or None,
            streams=not records_in_nodes(args.composed, args.recorder))
    if observers:
        spec = build_graph(cfg, args, args.schedule, mode, args.duration or 0.0, events,
                           observers)
    status = launch(spec, args, events, args.record, args.record_topics, args.log_dir,
                    args.duration is not None, cfg.plant.rate_hz, args.verbose)
    print("dcsms up: stopped", flush=True)
    return status


__all__ = ["add_deploy_options", "build_graph", "check_deploy_options", "launch", "register",
           "run"]
