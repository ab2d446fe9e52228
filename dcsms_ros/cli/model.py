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
from dcsms_ros.core.config import SystemConfig, scaled
from dcsms_ros.core.model import axis_names, input_slices, plant_state_space
from dcsms_ros.core.modes import Mode, parse_mode
from dcsms_ros.core.schema import resolve_alias
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


# ---------------------------------------------------------------------------------------------
# sweep


def top_stage_response(cfg: SystemConfig, axis: str, f_hz: Array) -> tuple[CArray, CArray]:
    """``v_pN/v_b`` and ``v_pN/F_i`` (force on table i along ``axis``, i = 1..N) of the passive
    plant: shapes (len(f),) and (len(f), N)."""
    ss = plant_state_space(cfg)
    g_sl, _, w_sl = input_slices(cfg)
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    j = axis_names(dof).index(axis)
    out_row = (n - 1) * dof + j
    from dcsms_ros.core.lti import ss_response

    s = 2j * math.pi * np.asarray(f_hz, dtype=float)
    cols = [g_sl.start + j] + [w_sl.start + i * dof + j for i in range(n)]
    h = [ss_response(ss.a, ss.b[:, [col]], ss.c[[out_row], :], 0.0, s) for col in cols]
    return h[0], np.stack(h[1:], axis=1)


def _eigenvalues_hz(cfg: SystemConfig) -> CArray:
    lam = np.linalg.eigvals(plant_state_space(cfg).a) / TWO_PI
    return np.asarray(sorted(lam, key=lambda z: (z.imag, z.real)), dtype=complex)


def _track(loci: Sequence[CArray]) -> CArray:
    """Reorder each step's eigenvalues to continue the nearest track of the step before
    (assignment problem), so lines and arrows follow one root; shape (steps, n_roots)."""
    from scipy.optimize import linear_sum_assignment

    tracks = [np.asarray(loci[0])]
    for lam in loci[1:]:
        cost = np.abs(tracks[-1][:, None] - np.asarray(lam)[None, :])
        _, col = linear_sum_assignment(cost)
        tracks.append(np.asarray(lam)[col])
    return np.vstack(tracks)


def _pick(n: int, k: int) -> list[int]:
    if n <= k:
        return list(range(n))
    return sorted({int(round(x)) for x in np.linspace(0, n - 1, k)})


def run_sweep(args: argparse.Namespace) -> int:
    """Scale ``--param`` by every factor; print/plot loci, FRC and PSD of the top stage."""
    base = load_cfg(args)
    _check_axis(base, args.axis)
    f = _grid(args)
    if args.curves < 1:
        raise ConfigError(f"--curves must be >= 1, got {args.curves}")
    if args.ground_psd < 0 or args.force_psd < 0:
        raise ConfigError("--ground-psd and --force-psd must be >= 0")
    name = resolve_alias(args.param)
    cfgs = [scaled(base, args.param, x) for x in args.factors]
    loci = [_eigenvalues_hz(c) for c in cfgs]
    modes = [oscillatory_modes(c) for c in cfgs]
    top = f"v_p{base.plant.num_stages}"
    picked = _pick(len(cfgs), args.curves)
    frc: list[CArray] = []
    psd: list[Array] = []
    for i in picked:
        h_g, h_f = top_stage_response(cfgs[i], args.axis, f)
        frc.append(h_g)
        psd.append(args.ground_psd * np.abs(h_g) ** 2
                   + args.force_psd * np.sum(np.abs(h_f) ** 2, axis=1))
    if args.json:
        print_json({
            "param": args.param, "name": name, "axis": args.axis, "factors": args.factors,
            "eigenvalues_hz": loci,
            "modes": [[_mode_dict(m) for m in ms] for ms in modes],
            "frequency_hz": f,
            "curves": [{"factor": args.factors[i], f"{top}/v_b_db": _db(h),
                        f"psd_{top}": p} for i, h, p in zip(picked, frc, psd, strict=True)],
        })
    else:
        _print_sweep(args.param, name, args.factors, modes)
    if args.plot is not None:
        d = plot_dir(args.plot)
        fig3 = d / f"fig3_{args.param}.png"
        fig6 = d / f"fig6_{args.param}.png"
        _plot_loci(fig3, args.param, args.factors, loci)
        _plot_frc_psd(fig6, args, top, f, [args.factors[i] for i in picked], frc, psd)
        if not args.json:
            print(f"wrote {fig3}\nwrote {fig6}")
    return 0


def _print_sweep(param: str, name: str, factors: Sequence[float],
                 modes: Sequence[Sequence[Any]]) -> None:
    width = max(len(m) for m in modes) if modes else 0
    print(f"sweep {param} ({name}) x factor: oscillatory modes f_n (Hz) / damping ratio")
    head = "".join(f"  {'f' + str(i + 1):>9} {'zeta' + str(i + 1):>9}" for i in range(width))
    print(f"{'factor':>8}{head}")
    for x, ms in zip(factors, modes, strict=True):
        cells = "".join(f"  {m.frequency_hz:>9.4f} {m.damping_ratio:>9.3e}" for m in ms)
        print(f"{x:>8.4g}{cells}")


def _plot_loci(out: Path, param: str, factors: Sequence[float], loci: Sequence[CArray]) -> None:
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    tracks = _track(loci)
    fig, ax = plt.subplots(figsize=(7, 5.5))
    norm = Normalize(min(factors), max(factors) if max(factors) > min(factors) else
                     min(factors) + 1)
    xs = np.repeat(np.asarray(factors, float)[:, None], tracks.shape[1], axis=1)
    sc = ax.scatter(tracks.real.ravel(), tracks.imag.ravel(), c=xs.ravel(), cmap="viridis",
                    norm=norm, s=12, zorder=3)
    for r in range(tracks.shape[1]):
        ax.plot(tracks[:, r].real, tracks[:, r].imag, color="0.6", lw=0.7, zorder=2)
        if len(factors) >= 2:
            # arrow over the last segment that moves: the direction of increasing factor
            seg = np.nonzero(np.abs(np.diff(tracks[:, r])) > 1e-9)[0]
            if len(seg):
                k = int(seg[len(seg) // 2])
                ax.annotate("", xy=(tracks[k + 1, r].real, tracks[k + 1, r].imag),
                            xytext=(tracks[k, r].real, tracks[k, r].imag),
                            arrowprops={"arrowstyle": "->", "color": "C3", "lw": 1.2})
    ax.axvline(0.0, color="k", lw=0.6)
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel("Re(lambda) / 2pi (Hz)")
    ax.set_ylabel("Im(lambda) / 2pi (Hz)")
    ax.set_title(f"Eigenvalue loci, {param} x factor {min(factors):g} ... {max(factors):g}")
    fig.colorbar(sc, ax=ax, label=f"factor on {param}")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def _plot_frc_psd(out: Path, args: argparse.Namespace, top: str, f: Array,
                  factors: Sequence[float], frc: Sequence[CArray], psd: Sequence[Array]) -> None:
    import matplotlib.pyplot as plt

    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(12, 4.8))
    for i, (x, h, p) in enumerate(zip(factors, frc, psd, strict=True)):
        ax_a.semilogx(f, _db(h), color=f"C{i % 10}", label=f"{args.param} x {x:g}")
        ax_b.loglog(f, p, color=f"C{i % 10}", label=f"{args.param} x {x:g}")
    ax_a.set_ylabel(f"|{top}/v_b| (dB)")
    ax_a.set_title(f"(a) FRC {top}/v_b, axis {args.axis}")
    ax_b.set_ylabel(f"PSD of {top} ((m/s)^2/Hz)")
    ax_b.set_title(f"(b) PSD: ground {args.ground_psd:g} (m/s)^2/Hz + "
                   f"table forces {args.force_psd:g} N^2/Hz")
    for ax in (ax_a, ax_b):
        ax.set_xlabel("frequency (Hz)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
