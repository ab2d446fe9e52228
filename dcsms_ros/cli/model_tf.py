"""``dcsms model tf``: transmissibility of every stage in a mode, with its margins."""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.cli.common import load_cfg, plot_dir, print_json
from dcsms_ros.cli.model_common import (
    AS_RUNS,
    IDEAL,
    MAX_TABLE_ROWS,
    Array,
    CArray,
    cell,
    check_axis,
    db,
    grid,
    phase,
)
from dcsms_ros.core import analytics
from dcsms_ros.core.margins import DiskMargin, LoopMargin, margins
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.sweep import transmissibility


def _loop_dict(m: LoopMargin) -> dict[str, float]:
    return {"gm_db": m.gm_db, "pm_deg": m.pm_deg, "wg_hz": m.wg_hz, "wp_hz": m.wp_hz}


def _disk_dict(d: DiskMargin) -> dict[str, Any]:
    return {"paths": list(d.paths), "alpha": d.alpha, "gm_db": d.gm_db, "pm_deg": d.pm_deg,
            "f_hz": d.f_hz}


def run(args: argparse.Namespace) -> int:
    """Transmissibility of every stage in ``--mode`` plus the margins."""
    cfg = load_cfg(args)
    check_axis(cfg, args.axis)
    f = grid(args, math.inf if args.ideal else cfg.plant.rate_hz / 2.0)
    mode: Mode = args.mode
    resp = transmissibility(cfg, mode, args.axis, f, args.ideal)
    passive = resp if mode is Mode.PASSIVE else transmissibility(cfg, Mode.PASSIVE, args.axis,
                                                                 f, args.ideal)
    loops: list[LoopMargin] = []
    disks: list[DiskMargin] = []
    if args.ideal:
        loops = [LoopMargin(c, args.axis, m.gm_db, m.pm_deg, m.wg_hz, m.wp_hz)
                 for c, m in analytics.loop_margins(cfg, mode, args.axis).items()]
    elif mode.controllers:
        every, disks = margins(cfg, mode)
        loops = [m for m in every if m.axis == args.axis]
    names = [f"v_p{i}/v_b" for i in range(1, len(resp) + 1)]
    if args.json:
        print_json({
            "model": "ideal" if args.ideal else "discrete", "mode": mode.label,
            "axis": args.axis, "frequency_hz": f,
            "transmissibility": {n: {"magnitude_db": db(h), "phase_deg": phase(h)}
                                 for n, h in zip(names, resp, strict=True)},
            "margins": {m.controller: _loop_dict(m) for m in loops},
            "disk_margins": {f"stage{d.stage}": _disk_dict(d) for d in disks},
        })
    else:
        print(f"{mode.label}, axis {args.axis}: {IDEAL if args.ideal else AS_RUNS}")
        _print_table(f, names, resp, passive)
        _print_margins(loops, disks)
    if args.plot is not None:
        out = plot_dir(args.plot) / f"bode_{mode.value}_{args.axis}.png"
        _plot_bode(out, mode, args.axis, f, names, resp, passive)
        print(f"wrote {out}")
    return 0


def _print_table(f: Array, names: Sequence[str], resp: Sequence[CArray],
                 passive: Sequence[CArray]) -> None:
    step = max(1, math.ceil(len(f) / MAX_TABLE_ROWS))
    print(f"transmissibility (dB, deg); every {step}th point, --json for all")
    head = "".join(f"  {n + ' dB':>14} {'deg':>8}" for n in names)
    print(f"{'f (Hz)':>10}{head}")
    dbs = [db(h) for h in resp]
    phs = [phase(h) for h in resp]
    for k in [*range(0, len(f) - 1, step), len(f) - 1]:
        cells = "".join(f"  {d[k]:>14.2f} {p[k]:>8.1f}" for d, p in zip(dbs, phs, strict=True))
        print(f"{f[k]:>10.4g}{cells}")
    for n, h, h0 in zip(names, resp, passive, strict=True):
        k = int(np.argmax(np.abs(h)))
        k0 = int(np.argmax(np.abs(h0)))
        print(f"peak {n}: {db(h)[k]:.2f} dB at {f[k]:.3f} Hz (passive {db(h0)[k0]:.2f} dB "
              f"at {f[k0]:.3f} Hz)")


def _print_margins(loops: Sequence[LoopMargin], disks: Sequence[DiskMargin]) -> None:
    if loops:
        # gain margin is read at the phase crossover (wp), phase margin at the gain crossover
        print(f"{'loop':<14} {'GM (dB)':>9} {'at (Hz)':>9} {'PM (deg)':>9} {'at (Hz)':>9}")
        for m in loops:
            print(f"{m.controller + '.' + m.axis:<14} {cell(m.gm_db, '9.2f'):>9} "
                  f"{cell(m.wp_hz, '9.3f'):>9} {cell(m.pm_deg, '9.2f'):>9} "
                  f"{cell(m.wg_hz, '9.3f'):>9}")
    for d in disks:
        print(f"stage{d.stage} disk margin (all {len(d.paths)} feedback paths at once): "
              f"+-{cell(d.gm_db, '.2f')} dB, +-{cell(d.pm_deg, '.1f')} deg "
              f"(alpha {d.alpha:.3f} at {cell(d.f_hz, '.3f')} Hz)")


def _plot_bode(out: Path, mode: Mode, axis: str, f: Array, names: Sequence[str],
               resp: Sequence[CArray], passive: Sequence[CArray]) -> None:
    import matplotlib.pyplot as plt  # noqa: PLC0415 - deferred: matplotlib

    fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(8, 6.5))
    for i, (n, h) in enumerate(zip(names, resp, strict=True)):
        colour = f"C{i}"
        ax_m.semilogx(f, db(h), color=colour, label=f"{n} ({mode.label})")
        ax_p.semilogx(f, phase(h), color=colour)
        if mode is not Mode.PASSIVE:
            ax_m.semilogx(f, db(passive[i]), color=colour, ls="--", lw=0.8,
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


__all__ = ["run"]
