"""``dcsms model check`` and ``dcsms model table4``: is a configuration safe, and what will it do.

``check`` judges every mode on the loop as it runs: stable, loop-at-a-time and disk margins at
least ``--min-gm``/``--min-pm``, every delay margin above ``control.input_timeout_s`` (the
latest a real-time force is applied), and no predicted saturation (peak = 4 x RMS of each actuator's
force under the configured disturbances). Exit 0 when every mode passes, 1 otherwise (each
failing mode named with why), 2 for a bad configuration. ``table4`` predicts the paper's Table 4
with the definition ``dcsms analyze`` uses.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from dcsms_ros.cli.common import load_cfg, print_json
from dcsms_ros.cli.model_common import AS_RUNS, cell
from dcsms_ros.core.check import PEAK_FACTOR, ModeCheck, check_config
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.errors import ConfigError


def _worst_loop(c: ModeCheck) -> tuple[float, float]:
    gm = min((abs(m.gm_db) for m in c.loops), default=math.inf)
    pm = min((m.pm_deg for m in c.loops), default=math.inf)
    return gm, pm


def _worst_disk(c: ModeCheck) -> tuple[float, float]:
    return (min((d.gm_db for d in c.disks), default=math.inf),
            min((d.pm_deg for d in c.disks), default=math.inf))


def _force(c: ModeCheck) -> tuple[str, float, float]:
    """(actuator, predicted peak N, its limit N) of the actuator nearest its limit."""
    if not len(c.actuators):
        return "-", 0.0, math.inf
    ratio = c.force_peak_n / c.force_limit_n
    i = int(np.argmax(np.where(np.isfinite(ratio), ratio, np.inf)))
    return c.actuators[i], float(c.force_peak_n[i]), float(c.force_limit_n[i])


def format_line(c: ModeCheck) -> str:
    """One line: mode, poles, worst loop and disk margins, force, verdict."""
    p = c.stability.worst_s_hz
    poles = (f"stable ({p.real:+.3f} Hz)" if c.stability.stable
             else f"UNSTABLE {p.real:+.4f}{p.imag:+.4f}j Hz")
    # margins of an unstable loop measure nothing useful: shown as "-"
    gm, pm = _worst_loop(c) if c.stability.stable else (math.nan, math.nan)
    dg, dp = _worst_disk(c) if c.stability.stable else (math.nan, math.nan)
    dm = c.delay_s[1] * 1e3 if c.stability.stable else math.nan
    name, peak, lim = _force(c)
    force = ("-" if not math.isfinite(peak) else
             f"{peak:.3g}/{lim:g} N {name}" if peak else "0 N")
    verdict = "OK" if c.ok else "FAIL"
    return (f"{c.mode.label:<9} {poles:<30} {cell(gm, '.1f'):>6} {cell(pm, '.0f'):>5}  "
            f"{cell(dg, '.1f'):>6} {cell(dp, '.0f'):>5}  {cell(dm, '.1f'):>6}  {force:<28} "
            f"{verdict}")


HEADER = (f"{'mode':<9} {'closed-loop poles (worst)':<30} {'loop':>6} {'':>5}  {'disk':>6} "
          f"{'':>5}  {'delay':>6}  {'peak force/limit, actuator':<28} verdict\n"
          f"{'':<9} {'':<30} {'GM dB':>6} {'PM':>5}  {'GM dB':>6} {'PM':>5}  {'DM ms':>6}")


def verdict_lines(checks: Sequence[ModeCheck]) -> list[str]:
    """The failing modes with why, or one line saying all passed (for start-up banners)."""
    bad = [c for c in checks if not c.ok]
    if not bad:
        line = (f"model check: all {len(checks)} modes stable with margins, no predicted "
                "saturation")
        return [line]
    return [f"model check: {c.mode.label} FAILS: {'; '.join(c.failures)}" for c in bad]


def _check_dict(c: ModeCheck) -> dict[str, Any]:
    st = c.stability
    return {
        "ok": c.ok, "stable": st.stable, "worst_pole_hz": st.worst_s_hz,
        "growth_per_s": st.growth_per_s,
        "unstable_poles_hz": list(st.unstable_s_hz),
        "loops": [{"controller": m.controller, "axis": m.axis, "gm_db": m.gm_db,
                   "pm_deg": m.pm_deg, "wg_hz": m.wg_hz, "wp_hz": m.wp_hz,
                   "delay_margin_s": m.delay_s} for m in c.loops],
        "delays": [{"name": d.name, "paths": list(d.paths), "delay_margin_s": d.delay_s,
                    "f_hz": d.f_hz} for d in c.delays],
        "disks": [{"stage": d.stage, "paths": list(d.paths), "alpha": d.alpha,
                   "gm_db": d.gm_db, "pm_deg": d.pm_deg, "f_hz": d.f_hz} for d in c.disks],
        "actuators": {n: {"rms_n": r, "peak_n": PEAK_FACTOR * r, "limit_n": lim}
                      for n, r, lim in zip(c.actuators, c.force_rms_n, c.force_limit_n,
                                           strict=True)},
        "failures": c.failures,
    }


def run_check(args: argparse.Namespace) -> int:
    """Handler of ``check``."""
    if not (args.min_gm >= 0 and args.min_pm >= 0 and math.isfinite(args.min_gm + args.min_pm)):
        raise ConfigError("--min-gm and --min-pm must be finite and >= 0")
    cfg = load_cfg(args)
    checks = check_config(cfg, min_gm_db=args.min_gm, min_pm_deg=args.min_pm)
    ok = all(c.ok for c in checks)
    if args.json:
        print_json({"config": cfg.source, "model": "discrete", "min_gm_db": args.min_gm,
                    "min_pm_deg": args.min_pm, "peak_factor": PEAK_FACTOR,
                    "input_timeout_s": cfg.control.input_timeout_s, "ok": ok,
                    "modes": {c.mode.label: _check_dict(c) for c in checks}})
        return 0 if ok else 1
    print(f"model check of {cfg.source} ({cfg.plant.fidelity}, {cfg.plant.num_stages} stages): "
          f"{AS_RUNS} at {cfg.plant.rate_hz:g} Hz")
    print(f"pass: stable, loop and disk margins >= {args.min_gm:g} dB / {args.min_pm:g} deg, "
          f"delay margin (DM, smallest of each path, each controller, all) above "
          f"control.input_timeout_s {cfg.control.input_timeout_s * 1e3:g} ms, every "
          f"actuator's peak force ({PEAK_FACTOR:g} x predicted RMS) within its limit")
    print(HEADER)
    for c in checks:
        print(format_line(c))
    if ok:
        print("model check: OK, every mode is safe to run")
        return 0
    for c in checks:
        if not c.ok:
            print(f"{c.mode.label}: {'; '.join(c.failures)}")
    names = ", ".join(c.mode.label for c in checks if not c.ok)
    print(f"model check: FAIL ({names})", file=sys.stderr)
    return 1


def run_table4(args: argparse.Namespace) -> int:
    """Handler of ``table4``."""
    # deferred: the prediction imports scipy.signal (0.8 s), not for every `dcsms` command
    from dcsms_ros.analysis import modetable  # noqa: PLC0415 - deferred for --help
    from dcsms_ros.analysis.predict import predict_table4, table_axes  # noqa: PLC0415 - as above

    cfg: SystemConfig = load_cfg(args)
    t = predict_table4(cfg)
    if args.json:
        print_json(t.to_dict())
        return 0
    axes = table_axes(cfg)
    print(f"Table 4 predicted for {cfg.source}: band RMS of the top stage's measured velocity "
          f"within 1/3 octave of the {t.reference} resonance ("
          + ", ".join(f"{a} {t.resonance_hz[a]:.3f} Hz" for a in axes)
          + f"), normalised to {t.reference}")
    rows = [{"mode": m, "axes": {a: {"normalized": v[a],
                                     "attenuation_db": modetable.normalize(v[a], 1.0)[1]}
                                 for a in axes}} for m, v in t.values.items()]
    print(modetable.format_table(rows, axes))
    unstable = [m for m, v in t.values.items() if not all(math.isfinite(x) for x in v.values())]
    if unstable:
        print(f"unstable (no stationary spectrum): {', '.join(unstable)}")
    return 0


__all__ = ["HEADER", "format_line", "run_check", "run_table4", "verdict_lines"]
