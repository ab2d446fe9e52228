"""``dcsms fit BAG...``: identify masses, suspensions and geophone parameters from the bags'
measured frequency responses (:mod:`dcsms_ros.analysis.identify`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import ProgressBar, print_json
from dcsms_ros.core.config import load_config
from dcsms_ros.errors import DcsmsError


def register(subparsers: Any) -> None:
    """Add the ``fit`` sub-command."""
    p = subparsers.add_parser(
        "fit", help="identify physical parameters from measured frequency responses",
        description="Weighted least squares of the loop model's mobility (from excited "
        "segments) and transmissibility against every usable bin of the bags (random error of "
        "|H1| <= 10 %), weighted by the coherence. Prints fitted values with standard "
        "deviations and the residual; --out writes the params YAML, JSON and plots.")
    p.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="rosbag2 directories")
    p.add_argument("--params", default=None, metavar="LIST",
                   help="comma-separated: m<i> k<i> c<i> (1dof), m<i> k<i><x|y|z> c<i><x|y|z> "
                   "(6dof), fg zg sg (geophone natural frequency, damping, sensitivity); "
                   "default: every mass, stiffness and damping (6dof: every suspension along "
                   "x y z)")
    p.add_argument("--config", type=Path, default=None, metavar="FILE",
                   help="the configuration the rig ran with (default: /dcsms/config of the "
                   "bags); the fit starts from its values")
    p.add_argument("--start", action="append", default=[], metavar="NAME=VALUE",
                   help="start value of a fitted parameter, e.g. --start m1=1100 (repeatable)")
    p.add_argument("--use", default="mobility,transmissibility", metavar="LIST",
                   help="responses to fit: mobility, transmissibility (default: both)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write fit.yaml (params file with the fitted values), fit.json and "
                   "fit_<response>_<axis>.png into DIR")
    p.add_argument("--json", action="store_true",
                   help='print {"parameters": {name: {"value", "std", ...}}, "residual_db", '
                   "...} on stdout")
    p.set_defaults(func=run)


def _starts(texts: list[str]) -> dict[str, float]:
    out = {}
    for t in texts:
        name, sep, value = t.partition("=")
        try:
            v = float(value)
        except ValueError:
            v = float("nan")
        if not sep or not v > 0:
            raise DcsmsError(f"--start {t!r}: expected NAME=VALUE with VALUE > 0")
        out[name.strip()] = v
    return out


def run(args: argparse.Namespace) -> int:
    """Handler: collect, fit, print (or JSON), write files."""
    # deferred: scipy, rosbags and the loop model, not for `dcsms --help`
    from dcsms_ros.analysis import identify, identify_fit  # noqa: PLC0415 - deferred for --help
    from dcsms_ros.analysis.frf import KINDS  # noqa: PLC0415 - deferred for --help

    kinds = [k.strip() for k in args.use.split(",") if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise DcsmsError(f"--use {args.use!r}: expected a list of {', '.join(KINDS)}")
    starts = _starts(args.start)
    cfg = load_config(args.config) if args.config is not None else None
    col = identify.collect(args.bags, cfg, kinds, progress=ProgressBar())
    params = identify.parse_params(col.cfg, args.params)
    result = identify_fit.fit(col, params, starts)
    files = identify_fit.write(result, args.out, args.bags) if args.out is not None else []
    if args.json:
        doc = result.to_dict()
        doc["files"] = [str(f) for f in files]
        doc["warnings"] = col.warnings
        print_json(doc)
        return 0
    print(f"fitted {len(params)} parameters to {result.bins} bins of {len(result.measured)} "
          f"responses ({result.evaluations} model evaluations):")
    print(f"{'name':<6}{'start':>13}{'fitted':>13}{'std':>11}{'change':>9}  unit")
    for p, s0, v, sd in zip(params, result.start, result.value, result.std, strict=True):
        print(f"{p.name:<6}{s0:>13.6g}{v:>13.6g}{sd:>11.3g}{100 * (v / s0 - 1):>+8.1f}%  "
              f"{p.unit}")
    print(f"residual {result.residual_db:.2f} dB RMS (start {result.residual_db_start:.2f} dB), "
          f"chi2/dof {result.chi2_reduced:.2f}")
    for w in col.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if files:
        print(f"wrote {len(files)} files to {args.out} (fit.yaml: params file with the fitted "
              "values)")
    return 0


__all__ = ["register", "run"]
