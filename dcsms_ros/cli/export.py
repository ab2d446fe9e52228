"""``dcsms export BAG``: time series of a bag as csv or npz tables in SI units
(:func:`dcsms_ros.analysis.tables.write_timeseries`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import ProgressBar

#: Topics exported when ``--topics`` is not given: what a vibration engineer asks for first.
DEFAULT_TOPICS = ("/dcsms/velocity/*", "/dcsms/force/*", "/dcsms/actuators/applied")


def register(subparsers: Any) -> None:
    """Add the ``export`` sub-command."""
    p = subparsers.add_parser(
        "export", help="write a bag's velocities and forces as csv or npz tables",
        description="Every component of the chosen topics in SI units (m/s, rad/s, N, N*m): "
        "npz arrays <name>_t_s, <name>_stamp_ns, <name>_<column>, or one csv file per topic "
        "with the units in the header; plus the mode timeline.")
    p.add_argument("bag", type=Path, metavar="BAG", help="rosbag2 directory")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC",
                   help="topics or patterns (default: " + " ".join(DEFAULT_TOPICS) + ", those "
                   "present); TwistStamped, WrenchStamped and JointState topics")
    p.add_argument("--format", choices=("csv", "npz"), default="csv",
                   help="csv (one file per topic, default) or npz (one file)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="output directory (default: BAG_export beside the bag)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler: export, print the files written."""
    # deferred: rosbags and scipy, not for `dcsms --help`
    from dcsms_ros.analysis.tables import write_timeseries  # noqa: PLC0415 - deferred for --help

    out = args.out if args.out is not None else args.bag.with_name(args.bag.name + "_export")
    # the default topics that the bag has (a bag without forces still exports); named ones
    # must exist
    names = args.topics if args.topics is not None else list(DEFAULT_TOPICS)
    files = write_timeseries(args.bag, out, names, args.format, ProgressBar(),
                             strict=args.topics is not None)
    print(f"wrote {len(files)} files to {out}")
    return 0


__all__ = ["DEFAULT_TOPICS", "register", "run"]
