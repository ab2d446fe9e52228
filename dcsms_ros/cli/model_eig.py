"""``dcsms model eig``: closed-loop poles / 2 pi, the oscillatory modes and the verdict."""

from __future__ import annotations

import argparse
from typing import Any

from dcsms_ros.cli.common import load_cfg, print_json
from dcsms_ros.cli.model_common import AS_RUNS, IDEAL, TWO_PI
from dcsms_ros.core import analytics
from dcsms_ros.core.check import Pole, ideal_poles, loop_poles, oscillatory
from dcsms_ros.core.modes import Mode


def _collapse(modes: list[Pole]) -> list[tuple[Pole, int]]:
    """Runs of equal poles of one part (identical sensor channels) as (pole, count)."""
    out: list[tuple[Pole, int]] = []
    for p in modes:
        if out and out[-1][0].part == p.part and abs(out[-1][0].s_hz - p.s_hz) <= 1e-6 * max(
                abs(p.s_hz), 1e-3):
            out[-1] = (out[-1][0], out[-1][1] + 1)
        else:
            out.append((p, 1))
    return out


def mode_dict(p: Pole) -> dict[str, Any]:
    """JSON of one oscillatory mode."""
    d: dict[str, Any] = {"eigenvalue_hz": p.s_hz, "frequency_hz": p.frequency_hz,
                         "damping_ratio": p.damping_ratio}
    if p.part:
        d["part"] = p.part
    return d


def _pole_dict(p: Pole) -> dict[str, Any]:
    d: dict[str, Any] = {"eigenvalue_hz": p.s_hz, "growth_per_s": TWO_PI * p.s_hz.real}
    if p.part:
        d.update(z_abs=abs(p.z), part=p.part)
    return d


def run(args: argparse.Namespace) -> int:
    """Print the modal table (or JSON) of the loop as it runs, or of ``--ideal``."""
    cfg = load_cfg(args)
    mode: Mode = args.mode
    poles = ideal_poles(cfg, mode) if args.ideal else loop_poles(cfg, mode)
    if args.ideal and mode is Mode.PASSIVE and cfg.plant.dof == 1:
        stable = bool(analytics.is_stable(cfg, mode))  # Routh-Hurwitz, as the paper argues
    else:
        stable = not any(p.unstable for p in poles)
    bad = [p for p in poles if p.unstable]
    worst = poles[0]
    modes = oscillatory(poles)
    if args.json:
        print_json({"model": "ideal" if args.ideal else "discrete", "mode": mode.label,
                    "stable": stable, "worst_pole": _pole_dict(worst),
                    "unstable_poles": [_pole_dict(p) for p in bad],
                    "modes": [mode_dict(p) for p in modes]})
        return 0
    what = IDEAL if args.ideal else f"{AS_RUNS} at {cfg.plant.rate_hz:g} Hz, s = fs ln(z)"
    print(f"{mode.label}: {cfg.plant.fidelity} model, {cfg.plant.num_stages} stages "
          f"({cfg.source}); {what}")
    part = "" if args.ideal else "  part (x identical poles)"
    print(f"{'mode':>4}  {'eigenvalue / 2pi (Hz)':>26}  {'f_n (Hz)':>9}  {'damping':>9}{part}")
    for i, (p, count) in enumerate(_collapse(modes), 1):
        lam = p.s_hz
        times = f" x{count}" if count > 1 else ""
        print(f"{i:>4}  {lam.real:>11.4f} +-{abs(lam.imag):>9.4f}i   {p.frequency_hz:>9.4f}  "
              f"{p.damping_ratio:>9.3e}" + ("" if args.ideal else f"  {p.part}{times}"))
    for p in bad:
        print(f"unstable pole {p.s_hz.real:+.4f} {p.s_hz.imag:+.4f}j Hz: growth "
              f"{TWO_PI * p.s_hz.real:.3g} /s" + (f" ({p.part})" if p.part else ""))
    if stable:
        how = ("Routh-Hurwitz" if args.ideal and mode is Mode.PASSIVE and cfg.plant.dof == 1
               else "eigenvalues" if args.ideal else "every pole inside the unit circle")
        print(f"stable ({how})")
    else:
        region = "left half-plane" if args.ideal else "unit circle"
        print(f"UNSTABLE: {len(bad)} poles outside the {region}; worst "
              f"{worst.s_hz.real:+.4f} {worst.s_hz.imag:+.4f}j Hz")
    return 0


__all__ = ["mode_dict", "run"]
