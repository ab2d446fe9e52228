"""``dcsms analyze BAG...``: per-mode transmissibility, the paper's Table 4, VC verdicts."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from dcsms_ros.analysis.paper import within
from dcsms_ros.cli.common import ProgressBar
from dcsms_ros.core.config import load_config
from dcsms_ros.errors import DcsmsError


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
    p.add_argument("--export", choices=("npz", "csv", "mat"), default=None,
                   help="also write every segment's spectra (frequency axis, complex H1 and "
                   "coherence, ASDs, one-third-octave RMS) into --out DIR as npz, csv or mat "
                   "tables")
    p.add_argument("--blrms", default="1-3,3-10,10-30", metavar="BANDS",
                   help="bands (Hz) of the band-limited RMS trends in the report and of each "
                   "segment's blrms_mps (default 1-3,3-10,10-30)")
    p.add_argument("--timeline-window", type=float, default=1.0, metavar="S",
                   help="window (s) of the timeline rows of a bag with supervisor transitions "
                   "or mode switches (default 1)")
    p.add_argument("--settle", type=float, default=None, metavar="S",
                   help="seconds dropped after each mode switch (default: per mode, the fade "
                   "plus 3 time constants of the new loop's slowest pole near the analysed band, "
                   "from the recorded configuration; at least 1 s)")
    p.add_argument("--paper", action="store_true", default=None,
                   help="compare with the paper's Table 4 (default: for a 6-DOF configuration)")
    p.set_defaults(func=run)


def _num(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.3f}"


def _estimates(ests: dict[str, Any]) -> str:
    """``mobility estimated (stage1 815, stage2 260 of 815 bins), transmissibility ...``."""
    parts = []
    for kind, v in ests.items():
        if v["status"] == "unavailable":
            parts.append(f"{kind} unavailable ({v['reason']})")
            continue
        bins = ", ".join(f"{s} {n}" for s, n in v["usable_bins"].items())
        parts.append(f"{kind} {v['status']} ({bins} of {v['band_bins']} bins)")
    return ", ".join(parts)


def run(args: argparse.Namespace) -> int:
    """Handler: analyse, print the mode table (or JSON), return 0."""
    # deferred (here and in every sub-command below): the analysis imports scipy and rosbags,
    # which `dcsms --help` (it imports every sub-command module) must not pay for
    from dcsms_ros.analysis.report import analyze, dumps  # noqa: PLC0415 - deferred for --help
    from dcsms_ros.analysis.timefreq import parse_bands  # noqa: PLC0415 - deferred for --help

    if args.export is not None and args.out is None:
        raise DcsmsError("--export needs --out DIR (the tables are written there)")
    bands = parse_bands(args.blrms)
    cfg = load_config(args.config) if args.config is not None else None
    summary = analyze(args.bags, reference=args.reference, out_dir=args.out, config=cfg,
                      progress=ProgressBar(), settle_s=args.settle, export=args.export,
                      blrms_bands=bands, paper=args.paper, timeline_s=args.timeline_window)
    if args.json:
        print(dumps(summary))
        return 0
    res = ", ".join(f"{a}: {f:.2f} Hz" for a, f in summary.resonance_hz.items())
    print(f"reference: {summary.reference} (resonance {res or 'n/a'})")
    print(summary.table())
    if summary.paper:
        print("paper Table 4 (ours / paper): " + "; ".join(
            f"{r['mode']} {r['axis']} {r['paper']:.3f}/{_num(r['ours'])}" for r in summary.paper)
            + f"; {within(summary.paper)} of {len(summary.paper)} within +-30 %")
    for seg in summary.segments:
        print(f"  {seg['segment']}: " + "; ".join(
            f"{a} {_estimates(seg['axes'][a]['estimates'])}" for a in summary.axes))
    for seg in summary.segments:
        vc = "; ".join(f"{a}: " + ", ".join(f"{t} {v['best'] or 'none'}"
                                           for t, v in seg["axes"][a]["vc"].items())
                       for a in summary.axes)
        print(f"  {seg['mode']:<10} VC {vc}")
    for bag, tl in summary.timelines:
        print(f"{bag}: " + "\n".join(tl.lines()))
    for w in summary.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if summary.files:
        print(f"wrote {len(summary.files)} files to {args.out}")
    return 0
