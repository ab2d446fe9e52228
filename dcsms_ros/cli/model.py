"""``dcsms model``: analytic results of the linear model (no simulation, no ROS).

``eig``    closed-loop poles / 2 pi (paper Eq. 9, Table 2 for Passive) and stability.
``routh``  Routh array of the characteristic polynomial and its verdict (paper section 2).
``tf``     |v_pi/v_b| of every stage in a control mode, with the margins (paper Eq. 10).
``check``  every mode: stable, margins, predicted actuator forces; exit 1 if one is unsafe.
``table4`` the paper's Table 4 predicted from the model.
``sweep``  one parameter scaled by a list of factors: eigenvalue loci (paper Fig. 3) and FRC +
           PSD of the top stage (paper Fig. 6).

``eig``, ``tf`` and ``check`` analyse the discrete loop as it runs (plant ZOH at the sample
rate, geophones, LF extension, decoupling, controller sections, allocation); ``--ideal`` gives
the paper's continuous model (Eq. 4/10: ideal sensors, continuous controllers), which is what
the paper's printed eigenvalues use. ``routh`` is always the paper's continuous polynomial.
"""

from __future__ import annotations

import argparse
import importlib
import math
import re
from collections.abc import Callable
from typing import Any

import numpy as np

from dcsms_ros.cli.common import (
    add_config_options,
    add_margin_options,
    add_output_options,
    load_cfg,
    print_json,
)
from dcsms_ros.cli.model_common import add_axis_and_grid, add_ideal, float_list, mode_arg

_PARAM_RE = re.compile(r"^[mck][1-9][0-9]*$")


def _handler(module: str, name: str = "run") -> Callable[[argparse.Namespace], int]:
    """A sub-command handler imported when it runs: python-control and the models take ~1.5 s
    to import, which `dcsms --help` and the other sub-commands should not pay."""
    def call(args: argparse.Namespace) -> int:
        func: Callable[[argparse.Namespace], int] = getattr(
            importlib.import_module(f"dcsms_ros.cli.{module}"), name)
        return func(args)
    return call


# ---------------------------------------------------------------------------------------------
# argument parsing


def register(subparsers: Any) -> None:
    """Add ``model`` and its sub-commands ``eig``, ``routh``, ``tf``, ``sweep``."""
    p = subparsers.add_parser("model", help="analytic model: eigenvalues, Routh, TFs, sweeps",
                              description=__doc__.replace("``", ""),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="model_command", metavar="WHAT", required=True)

    eig = sub.add_parser("eig", help="closed-loop poles/2pi, natural frequencies, damping ratios",
                         description="Poles of the loop as it runs (discrete: s = fs ln z) "
                         "divided by 2 pi (Hz, as the paper prints eigenvalues), one entry per "
                         "oscillatory mode, lowest first, the part of the loop each belongs "
                         "to, every unstable pole and the verdict.")
    add_config_options(eig)
    add_output_options(eig, plot=False)
    eig.add_argument("--mode", default="Passive", type=mode_arg,
                     help="closed-loop modes of this control mode (default: Passive)")
    add_ideal(eig)
    eig.set_defaults(func=_handler("model_eig"))

    routh = sub.add_parser("routh", help="Routh array of the characteristic polynomial",
                           description="Routh array of the passive characteristic polynomial "
                           "(or of --coeffs) and the stability verdict.")
    add_config_options(routh)
    add_output_options(routh, plot=False)
    routh.add_argument("--coeffs", type=float_list, default=None, metavar="A0,A1,...",
                       help="use these polynomial coefficients (highest power first) instead "
                       "of the configured plant")
    routh.set_defaults(func=run_routh)

    tf = sub.add_parser("tf", help="transmissibility |v_pi/v_b| of a control mode",
                        description="Transmissibility v_pi/v_b of every stage (dB and phase) "
                        "in one control mode, the loop-at-a-time margins of its feedback paths "
                        "and the disk margin of each stage.")
    add_config_options(tf)
    add_output_options(tf)
    tf.add_argument("--mode", default="Passive", type=mode_arg,
                    help="Passive, FBC, FFC, FBC+FFC, DFBC or DFBC+FFC (default: Passive)")
    add_axis_and_grid(tf)
    add_ideal(tf)
    tf.set_defaults(func=_handler("model_tf"))

    ck = sub.add_parser("check", help="is every mode safe: stable, margins, actuator forces",
                        description="Every mode on the loop as it runs: closed-loop poles, "
                        "loop-at-a-time and per-stage disk margins, predicted peak force "
                        "(4 x RMS) of each actuator against its limit, and a verdict. Exit 0 "
                        "when every mode is stable with the minimum margins and no predicted "
                        "saturation, 1 otherwise, 2 for a bad configuration. Run it before "
                        "driving a rig.")
    add_config_options(ck)
    add_output_options(ck, plot=False)
    add_margin_options(ck)
    ck.set_defaults(func=_handler("model_check", "run_check"))

    t4 = sub.add_parser("table4", help="the paper's Table 4 predicted from the model",
                        description="Band RMS of the top stage's measured velocity within one "
                        "third octave of the Passive resonance, per mode and axis, normalised "
                        "to Passive: the definition `dcsms analyze` uses, applied to the "
                        "spectrum the model predicts under the configured disturbances.")
    add_config_options(t4)
    add_output_options(t4, plot=False)
    t4.set_defaults(func=_handler("model_check", "run_table4"))

    sw = sub.add_parser("sweep", help="scale m1 m2 c1 c2 k1 k2: loci (Fig. 3), FRC/PSD (Fig. 6)",
                        description="Scale one passive parameter by each factor: eigenvalue "
                        "loci (paper Fig. 3) and |v_p2/v_b| plus the PSD of v_p2 (paper "
                        "Fig. 6; unit ground-velocity white noise and white force noise on "
                        "every table, uncorrelated).")
    add_config_options(sw)
    add_output_options(sw)
    sw.add_argument("--param", required=True, type=_param_arg, metavar="P",
                    help="m<i>, c<i> or k<i> of stage i, e.g. m1 m2 c1 c2 k1 k2")
    sw.add_argument("--factors", required=True, type=parse_factors, metavar="SPEC",
                    help="start:stop:step (inclusive, e.g. 1:101:2) or a comma list (0.5,1,2)")
    sw.add_argument("--curves", type=int, default=6, metavar="K",
                    help="number of factors drawn in the FRC/PSD figure (default 6)")
    sw.add_argument("--ground-psd", type=float, default=1.0, metavar="S",
                    help="one-sided PSD of the ground velocity, (m/s)^2/Hz (default 1)")
    sw.add_argument("--force-psd", type=float, default=1000.0, metavar="S",
                    help="one-sided PSD of the force on each table, N^2/Hz (default 1000, the "
                    "paper's '1000 units')")
    add_axis_and_grid(sw)
    sw.set_defaults(func=_handler("model_sweep", "sweep"))


def _param_arg(text: str) -> str:
    if not _PARAM_RE.match(text.strip()):
        raise argparse.ArgumentTypeError(
            f"unknown parameter {text!r}: use m<i>, c<i> or k<i> (m1 m2 c1 c2 k1 k2)")
    return text.strip()


def parse_factors(text: str) -> list[float]:
    """``start:stop:step`` (stop included when it lies on the grid) or ``a,b,c``.

    >>> parse_factors("1:7:2")
    [1.0, 3.0, 5.0, 7.0]
    """
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise argparse.ArgumentTypeError(f"expected start:stop:step, got {text!r}")
        start, stop, step = float_list(",".join(parts))
        if step <= 0 or stop < start:
            raise argparse.ArgumentTypeError(f"{text!r}: need step > 0 and stop >= start")
        n = int(math.floor((stop - start) / step + 1e-9))
        if n > 10_000:
            raise argparse.ArgumentTypeError(f"{text!r}: more than 10000 factors")
        # from the integer index, not by accumulation, so 0.1:10:0.1 ends exactly on 10
        values = [round(start + i * step, 12) for i in range(n + 1)]
    else:
        values = float_list(text)
    if any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: factors must be >= 0")
    return values


def run_routh(args: argparse.Namespace) -> int:
    """Print the Routh array of the characteristic polynomial and the verdict."""
    from dcsms_ros.core import analytics  # noqa: PLC0415 - deferred for --help

    if args.coeffs is not None:
        coeffs = np.asarray(args.coeffs, dtype=float)
        source = "--coeffs"
    else:
        cfg = load_cfg(args)
        coeffs = np.asarray(analytics.characteristic_polynomial(cfg), dtype=float)
        source = f"passive plant ({cfg.source})"
    result = analytics.routh(coeffs)
    rows = [np.asarray(r, dtype=float) for r in result.array]
    if args.json:
        print_json({"coefficients": coeffs, "array": rows,
                    "first_column": np.asarray(result.first_column, dtype=float),
                    "sign_changes": int(result.sign_changes), "stable": bool(result.stable)})
        return 0
    degree = len(coeffs) - 1
    print(f"characteristic polynomial of {source}, highest power first:")
    print("  " + "  ".join(f"{c:.6g}" for c in coeffs))
    print("Routh array:")
    for i, row in enumerate(rows):
        print(f"  s^{degree - i:<3}" + "".join(f"{x:>14.6g}" for x in row))
    verdict = "stable" if result.stable else "UNSTABLE"
    print(f"first column: {result.sign_changes} sign changes -> {verdict}")
    return 0
