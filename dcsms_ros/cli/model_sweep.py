"""``dcsms model sweep``: one parameter scaled by a list of factors.

Eigenvalue loci (paper Fig. 3) and the FRC and analytic PSD of the top stage (paper Fig. 6).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.cli.common import load_cfg, plot_dir, print_json
from dcsms_ros.cli.model_common import Array, CArray, check_axis, db, grid
from dcsms_ros.cli.model_eig import mode_dict
from dcsms_ros.core.schema import resolve_alias
from dcsms_ros.core.sweep import sweep as sweep_factors
from dcsms_ros.core.sweep import track
from dcsms_ros.errors import ConfigError


def sweep(args: argparse.Namespace) -> int:
    """Scale ``--param`` by every factor; print/plot loci, FRC and PSD of the top stage."""
    base = load_cfg(args)
    check_axis(base, args.axis)
    f = grid(args)
    if args.curves < 1:
        raise ConfigError(f"--curves must be >= 1, got {args.curves}")
    if args.ground_psd < 0 or args.force_psd < 0:
        raise ConfigError("--ground-psd and --force-psd must be >= 0")
    name = resolve_alias(args.param)
    sw = sweep_factors(base, args.param, args.factors, args.axis, f, args.ground_psd,
                       args.force_psd, args.curves)
    loci, modes, picked, frc, psd = sw.loci, sw.modes, sw.picked, sw.frc, sw.psd
    top = f"v_p{base.plant.num_stages}"
    if args.json:
        print_json({
            "param": args.param, "name": name, "axis": args.axis, "factors": args.factors,
            "eigenvalues_hz": loci,
            "modes": [[mode_dict(m) for m in ms] for ms in modes],
            "frequency_hz": f,
            "curves": [{"factor": args.factors[i], f"{top}/v_b_db": db(h),
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
    import matplotlib.pyplot as plt  # noqa: PLC0415 - deferred: matplotlib
    from matplotlib.colors import Normalize  # noqa: PLC0415 - deferred: matplotlib

    tracks = track(loci)
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
    import matplotlib.pyplot as plt  # noqa: PLC0415 - deferred: matplotlib

    fig, (ax_a, ax_b) = plt.subplots(1, 2, figsize=(12, 4.8))
    for i, (x, h, p) in enumerate(zip(factors, frc, psd, strict=True)):
        ax_a.semilogx(f, db(h), color=f"C{i % 10}", label=f"{args.param} x {x:g}")
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


__all__ = ["sweep"]
