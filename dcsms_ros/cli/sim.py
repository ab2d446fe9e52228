"""``dcsms sim``: simulate the closed loop and write the result as a bag.

``--engine batch`` runs :func:`dcsms_ros.core.engine.simulate` (no ROS) and writes the topics
a graph recording holds (:mod:`dcsms_ros.analysis.export`), with bag times and header stamps on
sim time, so ``dcsms analyze`` treats both alike. ``--engine graph`` runs the ROS graph in
lockstep while recording (``dcsms up --lockstep --record``).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import add_config_options, load_cfg
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
    p.set_defaults(func=run)


def parse_schedule(text: str) -> list[tuple[float, Any]]:
    """``"T:MODE,T:MODE"`` -> [(time s, Mode)], sorted; raises DcsmsError on bad items."""
    from dcsms_ros.core.modes import parse_mode

    out = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        t_text, sep, name = item.partition(":")
        try:
            t = float(t_text)
        except ValueError:
            t = float("nan")
        if not sep or not t >= 0.0:
            raise DcsmsError(f"--schedule {item!r}: expected TIME:MODE with TIME >= 0 s")
        out.append((t, parse_mode(name)))
    return sorted(out, key=lambda e: e[0])


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
    from dcsms_ros.core.modes import parse_mode

    if args.out.exists() or args.out.with_name(args.out.name + ".partial").exists():
        raise BagError(f"{args.out}: exists already, not overwriting")
    if not args.duration > 0:
        raise DcsmsError(f"--duration {args.duration}: must be > 0")
    mode = parse_mode(args.mode)
    schedule = parse_schedule(args.schedule)
    cfg = load_cfg(args)
    specs = parse_excitations(cfg, args.excite)
    plant = plant_config(cfg, args.plant_overrides)
    if args.engine == "graph":
        return _graph(args)
    ground = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if args.ground_from:
            from dcsms_ros.analysis.replay import load_ground, parse_ground_spec

            bag, topic = parse_ground_spec(args.ground_from)
            ground = load_ground(bag, topic, cfg.plant.rate_hz, cfg.plant.dof)
        res, counts, t_sim, t_write = _batch(args, cfg, mode, schedule, ground, specs, plant)
    for w in caught:
        print(f"dcsms: warning: {w.message}", file=sys.stderr)
    total = sum(counts.values())
    print(f"wrote {args.out}: {res.t.size} samples ({args.duration:g} s), {total} messages on "
          f"{len(counts)} topics; simulate {t_sim:.1f} s ({args.duration / t_sim:.1f}x real "
          f"time), write {t_write:.1f} s ({total / t_write:.0f} msg/s)")
    if res.counters.get("saturations"):
        print(f"dcsms: warning: {res.counters['saturations']} actuator saturation(s)",
              file=sys.stderr)
    return 0


def parse_excitations(cfg: Any, texts: Sequence[str]) -> list[Any]:
    """``--excite`` texts -> checked :class:`~dcsms_ros.core.excitation.ExcitationSpec` list."""
    from dcsms_ros.core.excitation import check_specs, parse_spec

    specs = [parse_spec(t) for t in texts]
    check_specs(cfg, specs)
    return specs


def plant_config(cfg: Any, texts: Sequence[str]) -> Any:
    """The plant of ``--plant-set NAME=VALUE`` overrides (None without any), checked against
    ``cfg`` (:func:`~dcsms_ros.core.simulator.check_plant`)."""
    from dcsms_ros.core.config import parse_override, with_overrides
    from dcsms_ros.core.simulator import check_plant

    if not texts:
        return None
    plant = with_overrides(cfg, dict(parse_override(t) for t in texts))
    check_plant(cfg, plant)
    return plant


def _batch(args: argparse.Namespace, cfg: Any, mode: Any, schedule: Sequence[Any],
           ground: Any, specs: Sequence[Any], plant: Any
           ) -> tuple[Any, dict[str, int], float, float]:
    from dcsms_ros.analysis.export import write_result_bag
    from dcsms_ros.core.engine import simulate
    from dcsms_ros.core.excitation import excitation_signal

    show = args.duration * cfg.plant.rate_hz > PROGRESS_MIN_STEPS
    t0 = time.perf_counter()
    bar = _Bar("simulate", show)
    steps = int(round(args.duration * cfg.plant.rate_hz))
    seed = cfg.disturbance.seed if args.seed is None else args.seed
    excite = excitation_signal(cfg, specs, steps, seed) if specs else None
    res = simulate(cfg, mode, args.duration, seed=args.seed, schedule=schedule, ground=ground,
                   progress=bar, excite=excite, plant=plant)
    bar(1.0)
    t1 = time.perf_counter()
    counts = write_result_bag(res, args.out, args.storage, clock=args.clock,
                              progress=_Bar("write", show))
    return res, counts, max(t1 - t0, 1e-9), max(time.perf_counter() - t1, 1e-9)


def _graph(args: argparse.Namespace) -> int:
    """The ROS graph in lockstep, recorded: ``dcsms up --lockstep --record OUT``.

    ``--seed`` becomes ``--set disturbance.seed=N`` (the batch engine's default seed too). The
    ``--ground-from`` becomes the plant's ``ground_from`` parameter, ``--excite`` the excitation
    node (active from sample 0, so the graph adds what the batch engine adds). The graph cannot
    take a mode schedule (switches go through the services at wall-clock times) or a plant that
    differs from the configuration, so those are refused.
    """
    if importlib.util.find_spec("dcsms_ros.cli.up") is None:
        raise DcsmsError("--engine graph: not available (needs `dcsms up`); use --engine batch")
    for flag, value in (("--schedule", args.schedule), ("--clock", args.clock),
                        ("--plant-set", args.plant_overrides)):
        if value:
            raise DcsmsError(f"--engine graph: {flag} is not supported yet; use --engine batch")
    if args.storage != "mcap":
        raise DcsmsError("--engine graph: only --storage mcap is supported")
    from dcsms_ros.cli import main

    argv = ["up", "--lockstep", "--record", str(args.out), "--duration", repr(args.duration),
            "--mode", args.mode]
    if args.config is not None:
        argv += ["--config", str(args.config)]
    for o in args.overrides:
        argv += ["--set", o]
    if args.seed is not None:
        argv += ["--set", f"disturbance.seed={args.seed}"]
    if args.ground_from:
        argv += ["--ground-from", args.ground_from]
    for spec in args.excite:  # the excitation node, active from sample 0 as in the batch run
        argv += ["--excite", spec]
    t0 = time.perf_counter()
    status = main(argv)
    if status == 0:
        print(f"wrote {args.out}: {args.duration:g} s in lockstep in "
              f"{time.perf_counter() - t0:.1f} s")
    return status


__all__ = ["parse_excitations", "parse_schedule", "plant_config", "register", "run"]
