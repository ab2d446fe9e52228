"""``dcsms sim``: simulate the closed loop and write the result as a bag.

``--engine batch`` runs the core engine without ROS, streaming (:mod:`dcsms_ros.analysis.
stream`): blocks of simulated time are written while the next is computed, so memory stays
bounded whatever the duration; the bag holds the topics a graph recording holds, with bag times
and header stamps on sim time, so ``dcsms analyze`` treats both alike. A run whose bag would not
fit on the disk, or whose duration is absurd, is refused before anything is written.
``--engine graph`` runs the ROS graph in lockstep while recording (``dcsms up --lockstep
--record``), one process per node or ``--composed``; a ``--schedule`` goes through the real
mode-switch services and lands on the same samples as in the batch engine, so both bags hold
the same numbers.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import (
    add_config_options,
    load_cfg,
    parse_excitations,
    parse_schedule,
    plant_config,
    print_model_check,
    refuse_unstable_start,
)
from dcsms_ros.cli.parts import records_in_nodes
from dcsms_ros.cli.up import add_deploy_options, build_graph, check_deploy_options, launch
from dcsms_ros.core.config import with_overrides
from dcsms_ros.core.modes import parse_mode
from dcsms_ros.errors import BagError, DcsmsError

#: Runs with more samples than this show a progress bar on stderr.
PROGRESS_MIN_STEPS = 20_000


def register(subparsers: Any) -> None:
    """Add the ``sim`` sub-command."""
    p = subparsers.add_parser(
        "sim", help="simulate the closed loop into a bag (batch or ROS graph)",
        description="Simulate a control mode (and a mode schedule) and write the same topics "
        "a graph recording holds into a new rosbag2 bag.")
    p.add_argument("--engine", choices=("batch", "graph"), default="batch",
                   help="batch: numeric core without ROS (fast); graph: the ROS graph in "
                   "lockstep, recorded (default: batch)")
    p.add_argument("--mode", default="passive", metavar="NAME",
                   help="mode at t = 0: passive, fbc, ffc, fbc_ffc, dfbc, dfbc_ffc")
    p.add_argument("--duration", type=float, required=True, metavar="S",
                   help="simulated time, s")
    p.add_argument("--seed", type=int, default=None, metavar="N",
                   help="seed of disturbances and sensor noise (default: from the config)")
    p.add_argument("--out", type=Path, required=True, metavar="BAG",
                   help="bag directory to create (must not exist)")
    add_config_options(p)
    p.add_argument("--schedule", default="", metavar="T:MODE,...",
                   help='later mode switches, e.g. "20:fbc,40:dfbc_ffc" (times in s)')
    p.add_argument("--ground-from", default=None, metavar="BAG[:TOPIC]",
                   help="replay a recorded ground velocity (TwistStamped; default topic "
                   "/dcsms/velocity/ground, else /dcsms/truth/ground) instead of noise, "
                   "resampled to the control rate")
    p.add_argument("--excite", action="append", default=[], metavar="SPEC",
                   help="actuator excitation added to the controllers' forces, e.g. "
                   "stage1.z:white:5 (5 N RMS, 0.5-100 Hz) or stage2.z:sweep:20:0.5-50 (20 N "
                   "sweep) or stage1.z:stepped:10:1-50:12; repeatable, one stage per run; "
                   "recorded on /dcsms/force/excitation")
    p.add_argument("--plant-set", action="append", default=[], metavar="NAME=VALUE",
                   dest="plant_overrides",
                   help="simulate a plant that differs from the configuration (masses, "
                   "suspensions, geophone dynamics, disturbances): the controllers and the "
                   "recorded /dcsms/config keep the configured values, as on a rig whose true "
                   "parameters are unknown (batch only; repeatable)")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap",
                   help="rosbag2 storage plugin (default: mcap)")
    p.add_argument("--clock", action="store_true",
                   help="also write /clock (left out by default, as the recorder does)")
    add_deploy_options(p)
    p.set_defaults(func=run)


class _Bar:
    """``label [####    ] 42%`` on stderr, redrawn at most 5 times a second."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label, self.enabled, self.last = label, enabled, 0.0

    def __call__(self, frac: float) -> None:
        now = time.monotonic()
        if not self.enabled or (frac < 1.0 and now - self.last < 0.2):
            return
        self.last = now
        sys.stderr.write(f"\r{self.label:<9} [{'#' * int(30 * frac):<30}] {100 * frac:5.1f}%")
        if frac >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()


def run(args: argparse.Namespace) -> int:
    """Handler: simulate, write the bag, print a one-line summary."""
    if args.out.exists() or args.out.with_name(args.out.name + ".partial").exists():
        raise BagError(f"{args.out}: exists already, not overwriting")
    mode = parse_mode(args.mode)
    schedule = parse_schedule(args.schedule)
    check_deploy_options(args)
    cfg = load_cfg(args)
    if args.seed is not None:  # the seed is a parameter of the graph's plant
        cfg = with_overrides(cfg, {"disturbance.seed": args.seed})
    # deferred (the analysis imports below too): the batch engine, python-control, scipy and
    # the bag writers, which `dcsms --help` must not pay for
    from dcsms_ros.analysis.stream import check_run  # noqa: PLC0415 - deferred for --help

    check_run(cfg, args.duration, args.out)  # nothing is written for a hopeless run
    specs = parse_excitations(cfg, args.excite)
    plant = plant_config(cfg, args.plant_overrides)
    if args.engine == "graph":
        return _graph(args, cfg, mode, schedule)
    print_model_check(cfg)
    ground = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if args.ground_from:
            from dcsms_ros.analysis.replay import (  # noqa: PLC0415 - deferred for --help
                load_ground,
                parse_ground_spec,
            )

            bag, topic = parse_ground_spec(args.ground_from)
            ground = load_ground(bag, topic, cfg.plant.rate_hz, cfg.plant.dof)
        from dcsms_ros.analysis.stream import stream_bag  # noqa: PLC0415 - deferred for --help

        t0 = time.perf_counter()
        res = stream_bag(cfg, mode, args.duration, args.out, schedule=schedule, ground=ground,
                         storage=args.storage, clock=args.clock,
                         progress=_Bar("simulate", args.duration * cfg.plant.rate_hz
                                       > PROGRESS_MIN_STEPS), excite=specs, plant=plant,
                         allow_unstable=args.allow_unstable)
        wall = max(time.perf_counter() - t0, 1e-9)
    for w in caught:
        print(f"dcsms: warning: {w.message}", file=sys.stderr)
    total = sum(res.counts.values())
    print(f"wrote {args.out}: {res.samples} samples ({args.duration:g} s), {total} messages on "
          f"{len(res.counts)} topics in {wall:.1f} s ({args.duration / wall:.1f}x real time, "
          f"{total / wall:.0f} msg/s)")
    for tr in res.supervision:
        print(f"dcsms: supervisor: {tr.label}", file=sys.stderr)
    if res.trip is not None:
        print(f"dcsms: warning: instability trip at t={(res.trip.sample + 1) / cfg.plant.rate_hz:g}"
              f" s: {res.trip.reason}; Passive from there"
              + (f"; refused: {', '.join(f'{m} at sample {k}' for k, m in res.refused)}"
                 if res.refused else ""), file=sys.stderr)
    if res.counters.get("saturations"):
        print(f"dcsms: warning: {res.counters['saturations']} actuator saturation(s)",
              file=sys.stderr)
    return 0


def _graph(args: argparse.Namespace, cfg: Any, mode: Any, schedule: list[Any]) -> int:
    """The ROS graph in lockstep, recorded (``dcsms up --lockstep --record OUT``).

    ``--seed`` becomes the plant's ``disturbance.seed``, ``--ground-from`` its ``ground_from``
    and ``--excite`` the excitation node (active from sample 0, so the graph adds what the
    batch engine adds); the recording holds the batch engine's topics.
    """
    for flag, value in (("--clock", args.clock), ("--storage sqlite3",
                                                 args.storage != "mcap"),
                        ("--plant-set", args.plant_overrides)):
        if value:
            raise DcsmsError(f"--engine graph: {flag} is not supported; use --engine batch")
    if args.ground_from:
        from dcsms_ros.analysis.replay import (  # noqa: PLC0415 - deferred for --help
            load_ground,
            parse_ground_spec,
        )

        bag, topic = parse_ground_spec(args.ground_from)
        load_ground(bag, topic, cfg.plant.rate_hz, cfg.plant.dof)
    print_model_check(cfg)
    refuse_unstable_start(cfg, mode, args.allow_unstable)
    spec = build_graph(cfg, args, "lockstep", mode, args.duration, schedule)
    nm = spec.names
    recorded = [nm.config, nm.mode, nm.supervisor_state, *spec.stream_topics()]
    spec = build_graph(cfg, args, "lockstep", mode, args.duration, schedule,
                       observers=spec.recorded_observed(
                           recorded, streams=not records_in_nodes(args.composed, args.recorder)))
    t0 = time.perf_counter()
    status = launch(spec, args, schedule, args.out, recorded, None, True, cfg.plant.rate_hz)
    if status == 0:
        wall = time.perf_counter() - t0
        print(f"wrote {args.out}: {args.duration:g} s in lockstep in {wall:.1f} s "
              f"({args.duration / wall:.2f}x real time)")
    return status


__all__ = ["register", "run"]
