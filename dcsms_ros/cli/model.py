"""``dcsms model``: analytic results of the linear model (no simulation, no ROS).

``eig``    eigenvalues / 2 pi of the passive cascade (paper Eq. 9, Table 2) and stability.
``routh``  Routh array of the characteristic polynomial and its verdict (paper section 2).
``tf``     |v_pi/v_b| of every stage in a control mode, with the loop margins (paper Eq. 10).
``sweep``  one parameter scaled by a list of factors: eigenvalue loci (paper Fig. 3) and FRC +
           PSD of the top stage (paper Fig. 6).
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.cli.common import (
    add_config_options,
    add_output_options,
    load_cfg,
    plot_dir,
    print_json,
)
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.model import axis_names
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.errors import ConfigError, DcsmsError

# dcsms_ros.core.analytics imports python-control (~1.5 s): imported where it is used, so that
# `dcsms --help` and the other sub-commands stay fast.

Array = NDArray[np.float64]
CArray = NDArray[np.complex128]

TWO_PI = 2.0 * math.pi
#: Most rows a plain-text frequency table prints (``--json`` always has every point).
MAX_TABLE_ROWS = 41
_PARAM_RE = re.compile(r"^[mck][1-9][0-9]*$")


# ---------------------------------------------------------------------------------------------
# argument parsing


def register(subparsers: Any) -> None:
    """Add ``model`` and its sub-commands ``eig``, ``routh``, ``tf``, ``sweep``."""
    p = subparsers.add_parser("model", help="analytic model: eigenvalues, Routh, TFs, sweeps",
                              description=__doc__.replace("``", ""),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="model_command", metavar="WHAT", required=True)

    eig = sub.add_parser("eig", help="eigenvalues/2pi, natural frequencies, damping ratios",
                         description="Eigenvalues of the passive cascade divided by 2 pi (Hz, "
                         "as the paper prints them), one entry per oscillatory mode, lowest "
                         "first, and the Routh-Hurwitz verdict.")
    add_config_options(eig)
    add_output_options(eig, plot=False)
    eig.add_argument("--mode", default="Passive", type=_mode_arg,
                     help="closed-loop modes of this control mode (default: Passive)")
    eig.set_defaults(func=run_eig)

    routh = sub.add_parser("routh", help="Routh array of the characteristic polynomial",
                           description="Routh array of the passive characteristic polynomial "
                           "(or of --coeffs) and the stability verdict.")
    add_config_options(routh)
    add_output_options(routh, plot=False)
    routh.add_argument("--coeffs", type=_float_list, default=None, metavar="A0,A1,...",
                       help="use these polynomial coefficients (highest power first) instead "
                       "of the configured plant")
    routh.set_defaults(func=run_routh)

    tf = sub.add_parser("tf", help="transmissibility |v_pi/v_b| of a control mode",
                        description="Analytic transmissibility v_pi/v_b of every stage (dB and "
                        "phase) in one control mode, and the loop margins of its controllers.")
    add_config_options(tf)
    add_output_options(tf)
    tf.add_argument("--mode", default="Passive", type=_mode_arg,
                    help="Passive, FBC, FFC, FBC+FFC, DFBC or DFBC+FFC (default: Passive)")
    _add_axis_and_grid(tf)
    tf.set_defaults(func=run_tf)

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
    _add_axis_and_grid(sw)
    sw.set_defaults(func=run_sweep)


def _add_axis_and_grid(p: argparse.ArgumentParser) -> None:
    p.add_argument("--axis", default="z", choices=("x", "y", "z", "rx", "ry", "rz"),
                   help="axis of a 6dof model (1dof: z only; default z)")
    p.add_argument("--fmin", type=float, default=0.1, help="lowest frequency, Hz (default 0.1)")
    p.add_argument("--fmax", type=float, default=100.0, help="highest frequency, Hz (default 100)")
    p.add_argument("--points", type=int, default=400,
                   help="log-spaced frequency points (default 400)")


def _mode_arg(text: str) -> Mode:
    try:
        return parse_mode(text)
    except DcsmsError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _param_arg(text: str) -> str:
    if not _PARAM_RE.match(text.strip()):
        raise argparse.ArgumentTypeError(
            f"unknown parameter {text!r}: use m<i>, c<i> or k<i> (m1 m2 c1 c2 k1 k2)")
    return text.strip()


def _float_list(text: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}")
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def parse_factors(text: str) -> list[float]:
    """``start:stop:step`` (stop included when it lies on the grid) or ``a,b,c``.

    >>> parse_factors("1:7:2")
    [1.0, 3.0, 5.0, 7.0]
    """
    if ":" in text:
        parts = text.split(":")
        if len(parts) != 3:
            raise argparse.ArgumentTypeError(f"expected start:stop:step, got {text!r}")
        start, stop, step = _float_list(",".join(parts))
        if step <= 0 or stop < start:
            raise argparse.ArgumentTypeError(f"{text!r}: need step > 0 and stop >= start")
        n = int(math.floor((stop - start) / step + 1e-9))
        if n > 10_000:
            raise argparse.ArgumentTypeError(f"{text!r}: more than 10000 factors")
        # from the integer index, not by accumulation, so 0.1:10:0.1 ends exactly on 10
        values = [round(start + i * step, 12) for i in range(n + 1)]
    else:
        values = _float_list(text)
    if any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: factors must be >= 0")
    return values


def _grid(args: argparse.Namespace) -> Array:
    if not (0 < args.fmin < args.fmax and math.isfinite(args.fmax)):
        raise ConfigError(f"need 0 < --fmin < --fmax, got {args.fmin:g} and {args.fmax:g}")
    if not 2 <= args.points <= 100_000:
        raise ConfigError(f"--points must be in [2, 100000], got {args.points}")
    return np.logspace(math.log10(args.fmin), math.log10(args.fmax), args.points)


def _check_axis(cfg: SystemConfig, axis: str) -> None:
    if axis not in axis_names(cfg.plant.dof):
        raise ConfigError(f"--axis {axis}: a {cfg.plant.fidelity} model has only "
                          f"{', '.join(axis_names(cfg.plant.dof))}")


# ---------------------------------------------------------------------------------------------
# eig / routh


def oscillatory_modes(cfg: SystemConfig, mode: Mode = Mode.PASSIVE) -> list[Any]:
    """``analytics.modes``: one entry per oscillatory mode (Im > 0), lowest frequency first."""
    from dcsms_ros.core import analytics

    modes = [m for m in analytics.modes(cfg, mode) if complex(m.eigenvalue_hz).imag > 0]
    return sorted(modes, key=lambda m: float(m.frequency_hz))


def _mode_dict(m: Any) -> dict[str, Any]:
    return {"eigenvalue_hz": complex(m.eigenvalue_hz), "frequency_hz": float(m.frequency_hz),
            "damping_ratio": float(m.damping_ratio)}


def run_eig(args: argparse.Namespace) -> int:
    """Print the modal table (or JSON) of the passive plant or of a closed loop."""
    cfg = load_cfg(args)  # first: a config error needs no python-control import
    from dcsms_ros.core import analytics

    mode: Mode = args.mode
    stable = bool(analytics.is_stable(cfg, mode))
    modes = oscillatory_modes(cfg, mode)
    if args.json:
        print_json({"stable": stable, "modes": [_mode_dict(m) for m in modes]})
        return 0
    print(f"{mode.label}: {cfg.plant.fidelity} model, {cfg.plant.num_stages} stages "
          f"({cfg.source})")
    print(f"{'mode':>4}  {'eigenvalue / 2pi (Hz)':>26}  {'f_n (Hz)':>9}  {'damping':>9}")
    for i, m in enumerate(modes, 1):
        lam = complex(m.eigenvalue_hz)
        print(f"{i:>4}  {lam.real:>11.4f} +-{abs(lam.imag):>9.4f}i   {m.frequency_hz:>9.4f}  "
              f"{m.damping_ratio:>9.3e}")
    how = "Routh-Hurwitz" if mode is Mode.PASSIVE and cfg.plant.dof == 1 else "eigenvalues"
    print(f"{'stable' if stable else 'UNSTABLE'} ({how})")
    return 0


def run_routh(args: argparse.Namespace) -> int:
    """Print the Routh array of the characteristic polynomial and the verdict."""
    from dcsms_ros.core import analytics

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


# ---------------------------------------------------------------------------------------------
# tf


def run_tf(args: argparse.Namespace) -> int:
    """Transmissibility of every stage in ``--mode`` plus the loop margins."""
    from dcsms_ros.core import analytics

    cfg = load_cfg(args)
    _check_axis(cfg, args.axis)
    f = _grid(args)
    mode: Mode = args.mode
    resp = [analytics.freq_response(tf, f) for tf in analytics.transmissibility(cfg, mode,
                                                                                args.axis)]
    passive = resp if mode is Mode.PASSIVE else [
        analytics.freq_response(tf, f)
        for tf in analytics.transmissibility(cfg, Mode.PASSIVE, args.axis)]
    margins = analytics.loop_margins(cfg, mode, args.axis) if mode.controllers else {}
    names = [f"v_p{i}/v_b" for i in range(1, len(resp) + 1)]
    if args.json:
        print_json({
            "mode": mode.label, "axis": args.axis, "frequency_hz": f,
            "transmissibility": {n: {"magnitude_db": _db(h), "phase_deg": _phase(h)}
                                 for n, h in zip(names, resp, strict=True)},
            "margins": {k: _margin_dict(m) for k, m in margins.items()},
        })
    else:
        _print_tf_table(mode, args.axis, f, names, resp, passive)
        _print_margins(margins)
    if args.plot is not None:
        out = plot_dir(args.plot) / f"bode_{mode.value}_{args.axis}.png"
        _plot_bode(out, mode, args.axis, f, names, resp, passive)
        print(f"wrote {out}")
    return 0


def _db(h: CArray) -> Array:
    return np.asarray(20.0 * np.log10(np.maximum(np.abs(h), 1e-300)))


def _phase(h: CArray) -> Array:
    return np.asarray(np.degrees(np.unwrap(np.angle(h))))


def _margin_dict(m: Any) -> dict[str, float]:
    return {k: float(getattr(m, k)) for k in ("gm_db", "pm_deg", "wg_hz", "wp_hz")}


def _print_tf_table(mode: Mode, axis: str, f: Array, names: Sequence[str],
                    resp: Sequence[CArray], passive: Sequence[CArray]) -> None:
    print(f"{mode.label}, axis {axis}: transmissibility (dB, deg); every "
          f"{max(1, math.ceil(len(f) / MAX_TABLE_ROWS))}th point, --json for all")
    head = "".join(f"  {n + ' dB':>14} {'deg':>8}" for n in names)
    print(f"{'f (Hz)':>10}{head}")
    step = max(1, math.ceil(len(f) / MAX_TABLE_ROWS))
    dbs = [_db(h) for h in resp]
    phs = [_phase(h) for h in resp]
    for k in [*range(0, len(f) - 1, step), len(f) - 1]:
        cells = "".join(f"  {db[k]:>14.2f} {ph[k]:>8.1f}" for db, ph in zip(dbs, phs,
                                                                           strict=True))
        print(f"{f[k]:>10.4g}{cells}")
    for n, h, h0 in zip(names, resp, passive, strict=True):
        k = int(np.argmax(np.abs(h)))
        k0 = int(np.argmax(np.abs(h0)))
        print(f"peak {n}: {_db(h)[k]:.2f} dB at {f[k]:.3f} Hz (passive {_db(h0)[k0]:.2f} dB "
              f"at {f[k0]:.3f} Hz)")


def _print_margins(margins: dict[str, Any]) -> None:
    if not margins:
        return
    def cell(x: float, fmt: str) -> str:
        return format(x, fmt) if math.isfinite(x) else ("inf" if math.isinf(x) else "-")

    # gain margin is read at the phase crossover (wp), phase margin at the gain crossover (wg)
    print(f"{'loop':<12} {'GM (dB)':>9} {'at (Hz)':>9} {'PM (deg)':>9} {'at (Hz)':>9}")
    for name, m in margins.items():
        print(f"{name:<12} {cell(m.gm_db, '9.2f'):>9} {cell(m.wp_hz, '9.3f'):>9} "
              f"{cell(m.pm_deg, '9.2f'):>9} {cell(m.wg_hz, '9.3f'):>9}")


def _plot_bode(out: Path, mode: Mode, axis: str, f: Array, names: Sequence[str],
               resp: Sequence[CArray], passive: Sequence[CArray]) -> None:
    import matplotlib.pyplot as plt

    fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(8, 6.5))
    for i, (n, h) in enumerate(zip(names, resp, strict=True)):
        colour = f"C{i}"
        ax_m.semilogx(f, _db(h), color=colour, label=f"{n} ({mode.label})")
        ax_p.semilogx(f, _phase(h), color=colour)
        if mode is not Mode.PASSIVE:
            ax_m.semilogx(f, _db(passive[i]), color=colour, ls="--", lw=0.8,
                          label=f"{n} (Passive)")
    ax_m.set_ylabel("magnitude (dB)")
    ax_p.set_ylabel("phase (deg)")
    ax_p.set_xlabel("frequency (Hz)")
    ax_m.set_title(f"Transmissibility, {mode.label}, axis {axis}")
    ax_m.legend(fontsize=8)
    for ax in (ax_m, ax_p):
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def run_sweep(args: argparse.Namespace) -> int:
    """Handler of ``sweep`` (in :mod:`dcsms_ros.cli.model_sweep`, imported when used)."""
    from dcsms_ros.cli.model_sweep import sweep

    return sweep(args)

