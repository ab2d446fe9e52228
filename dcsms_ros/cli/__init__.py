"""The ``dcsms`` command: one argparse sub-command per module of this package.

Each module ``dcsms_ros/cli/<name>.py`` exposes ``register(subparsers) -> None``, which adds its
parser and sets ``func`` (``func(args) -> int | None``) with ``set_defaults``. Modules that do not
exist yet are skipped, so the command grows as the project does.

Building the parser imports every sub-command module, so ``dcsms --help`` pays for their
module-level imports. A handler therefore imports the heavy APIs it calls (the analysis, the
batch engine, python-control, matplotlib, rclpy) when it runs; each such import is marked
``# noqa: PLC0415 - deferred ...`` (ruff's import-outside-top-level). None of them hides an
import cycle: ``test/test_structure.py`` checks the package's import graph, function-local
imports included.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from dcsms_ros import __version__
from dcsms_ros.errors import DcsmsError
from dcsms_ros.rosenv import keep_discovery_local

#: Sub-command modules, in the order ``dcsms --help`` lists them.
SUBCOMMANDS: tuple[str, ...] = ("model", "tune", "sim", "up", "mode", "record", "recover",
                                "analyze", "fit", "export", "demo", "params")

#: Exit status of a usage or configuration error (the argparse convention).
EXIT_USAGE = 2
#: Exit status after Ctrl-C (128 + SIGINT), the shell convention.
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every available sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="dcsms",
        description="Dual-stage cascade spring-mass isolation: model, simulate, run the ROS 2 "
        "graph, record and analyse.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        module_name = f"{__name__}.{name}"
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            # Only a missing sub-command module is skipped; a missing dependency *inside* an
            # existing module is a real bug and must surface.
            if exc.name == module_name:
                continue
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``dcsms`` with ``argv`` (default: ``sys.argv[1:]``) and return the exit status.

    Returns
    -------
    int
        0 on success, 2 for a usage or configuration error (one line on stderr), 1 for a
        file the system refused (one line: the path and the reason), 130 after Ctrl-C, or
        what the sub-command returned.
    """
    # Any ROS participant this process starts must stay on this machine unless told otherwise.
    keep_discovery_local()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help/--version (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    try:
        status = func(args)
    except DcsmsError as exc:
        print(f"dcsms: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # `dcsms ... | head`: the reader left; silence the interpreter's flush at exit too.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except OSError as exc:  # a full disk, a directory removed or read-only: not our defect
        print(f"dcsms: error: {exc}", file=sys.stderr)
        return 1
    return int(status or 0)


__all__ = ["EXIT_INTERRUPTED", "EXIT_USAGE", "SUBCOMMANDS", "build_parser", "main"]
