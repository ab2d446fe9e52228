"""``dcsms analyze BAG...``: per-mode transmissibility, the paper's Table 4, VC verdicts."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

#: Without a terminal, seconds between two progress lines (and before the first).
PIPE_PERIOD_S = 10.0
#: Bags with fewer messages finish in about a second: no progress bar for them.
PROGRESS_MIN_MESSAGES = 200_000


def register(subparsers: Any) -> None:
    """Add the ``analyze`` sub-command."""
    p = subparsers.add_parser(
        "analyze", help="analyse recorded bags mode by mode",
        description="Split bags by /dcsms/mode, estimate transmissibility (Welch H1) and "
        "coherence, the paper's Table 4 (top-stage velocity at the Passive resonance, "
        "normalised), one-third-octave VC verdicts and actuator forces.")
    p.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="rosbag2 directories")
    p.add_argument("--reference", default="passive",
                   help="mode to normalise to (default: passive)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write report.md, PNG plots and summary.json into DIR")
    p.add_argument("--json", action="store_true", help="print summary JSON on stdout")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="params YAML overriding the configuration recorded in the bag")
    p.add_argument("--settle", type=float, default=1.0, metavar="S",
                   help="seconds dropped after each mode switch (default 1.0)")
    p.set_defaults(func=run)


class _ProgressBar:
    """Progress of a long bag on stderr: a redrawn bar on a terminal; elsewhere (a log, a pipe)
    a whole line every :data:`PIPE_PERIOD_S`, the first after that long, so a bag that fails
    early gives its one-line error and nothing else."""

    def __init__(self, stream: Any = None) -> None:
        self._stream = stream  # None: sys.stderr as it is when the bar is first drawn
        self.tty: bool | None = None
        self.last = time.monotonic()
        self.shown = False

    @property
    def stream(self) -> Any:
        return self._stream if self._stream is not None else sys.stderr

    def __call__(self, done: int, total: int) -> None:
        if total < PROGRESS_MIN_MESSAGES:
            return
        if self.tty is None:
            self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
            if self.tty:
                self.last = 0.0
        now = time.monotonic()
        period = 0.2 if self.tty else PIPE_PERIOD_S
        if now - self.last < period and (done < total or not self.shown):
            return
        self.last = now
        frac = min(done / total, 1.0) if total else 1.0
        bar = "#" * int(30 * frac)
        text = f"reading [{bar:<30}] {100 * frac:5.1f}% ({done}/{total} msgs)"
        self.stream.write(f"\r{text}" + ("\n" if done >= total else "") if self.tty
                          else text + "\n")
        self.shown = True
        self.stream.flush()


def run(args: argparse.Namespace) -> int:
    """Handler: analyse, print the mode table (or JSON), return 0."""
    from dcsms_ros.analysis.report import analyze, dumps
    from dcsms_ros.core.config import load_config

    cfg = load_config(args.config) if args.config is not None else None
    summary = analyze(args.bags, reference=args.reference, out_dir=args.out, config=cfg,
                      progress=_ProgressBar(), settle_s=args.settle)
    if args.json:
        print(dumps(summary))
        return 0
    res = ", ".join(f"{a}: {f:.2f} Hz" for a, f in summary.resonance_hz.items())
    print(f"reference: {summary.reference} (resonance {res or 'n/a'})")
    print(summary.table())
    for seg in summary.segments:
        vc = "; ".join(f"{a}: " + ", ".join(f"{t} {v['best'] or 'none'}"
                                           for t, v in seg["axes"][a]["vc"].items())
                       for a in summary.axes)
        print(f"  {seg['mode']:<10} VC {vc}")
    for w in summary.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if summary.files:
        print(f"wrote {len(summary.files)} files to {args.out}")
    return 0
