"""``dcsms record OUT``: record the graph's topics into a rosbag2 bag until Ctrl-C/SIGTERM.

The recorder runs in this process (:func:`dcsms_ros.nodes.recorder.record`); SIGINT and SIGTERM
end it cleanly with exit status 0 after every queued message was written, and the per-topic
counts and gaps are printed on stdout. ``dcsms up --record OUT`` starts the same command as a
child process (:func:`dcsms_ros.cli.deploy.recorder_command`) and stops it with SIGINT.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import print_json
from dcsms_ros.cli.deploy import recorder_command
from dcsms_ros.errors import BagError, DcsmsError

STORAGES = ("mcap", "sqlite3")


def register(subparsers: Any) -> None:
    """Add the ``record`` sub-command."""
    p = subparsers.add_parser(
        "record", help="record the graph's topics into a bag",
        description="Record topics (default: every /dcsms/* topic, discovered as they appear; "
        "/clock only when named) into a new rosbag2 bag. Ctrl-C or SIGTERM stops cleanly: "
        "the bag is closed, nothing received is lost, counts and gaps are printed.")
    p.add_argument("out", type=Path, metavar="OUT", help="bag directory to create (must not "
                   "exist)")
    p.add_argument("--topics", nargs="+", metavar="T", default=None,
                   help="topic names or fnmatch patterns (default: /dcsms/*)")
    p.add_argument("--exclude", nargs="+", metavar="T", default=None,
                   help="topic names or fnmatch patterns not to record (default: none)")
    p.add_argument("--storage", choices=STORAGES, default="mcap",
                   help="rosbag2 storage plugin (default: mcap)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds of wall time (default: until Ctrl-C/SIGTERM)")
    p.add_argument("--queue-depth", type=int, default=None, metavar="N",
                   help="reader history per topic (default 4000: 2 s at 2 kHz)")
    p.add_argument("--json", action="store_true",
                   help="print the counts and gaps as JSON on stdout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler: record, print the report, return 0."""
    if args.out.exists() or args.out.with_name(args.out.name + ".partial").exists():
        raise BagError(f"{args.out}: exists already, not overwriting")
    if args.duration is not None and not args.duration > 0:
        raise DcsmsError(f"--duration {args.duration}: must be > 0")
    from dcsms_ros.nodes.recorder import record  # noqa: PLC0415 - deferred: ROS

    if args.queue_depth is not None and args.queue_depth < 1:
        raise DcsmsError(f"--queue-depth {args.queue_depth}: must be >= 1")
    rec = record(str(args.out), args.topics, args.storage, args.duration, args=[],
                 queue_depth=args.queue_depth, exclude=args.exclude)
    if args.json:
        print_json(rec.as_dict())
    else:
        print(rec.text(), flush=True)
    return 0


__all__ = ["recorder_command", "register", "run"]
