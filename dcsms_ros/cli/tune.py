"""``dcsms tune``: choose controller gains on the model of the loop as it runs.

Searches the feedback gains per stage and axis and the feedforward gain (``--corners``: also
the high-pass and sensor-extension corners; ``--rotations``: also rotational gains in 6dof) for
the best objective subject to: every mode stable, every loop and disk margin at least
``--min-gm``/``--min-pm``, every actuator's predicted force RMS at most a quarter of its limit.
Writes a loadable params file whose header says how it was made, checks it with
``dcsms model check``'s judgement, then runs each mode in the batch engine and prints the
predicted and simulated Table 4 side by side. Exit 0 with a result, 1 when no candidate
satisfied the constraints (nothing is written), 2 for bad input.
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from dcsms_ros.cli.common import add_config_options, add_margin_options, load_cfg, print_json
from dcsms_ros.core.modes import ALL_MODES, parse_mode
from dcsms_ros.errors import ConfigError, DcsmsError, ModeError


def register(subparsers: Any) -> None:
    """Add the ``tune`` sub-command."""
    p = subparsers.add_parser("tune", help="choose controller gains on the model (constrained)",
                              description=__doc__.replace("``", "`"),
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_options(p)
    p.add_argument("--out", type=Path, required=True, metavar="OUT.yaml",
                   help="params file to write (must not exist)")
    p.add_argument("--objective", choices=("attenuation", "table4"), default="attenuation",
                   help="attenuation: lowest DFBC+FFC Table-4 value on every axis; table4: "
                   "closest to --target (default attenuation)")
    p.add_argument("--target", type=Path, default=None, metavar="FILE",
                   help="YAML mode -> axis -> factor, e.g. 'FBC: {x: 0.243, y: 1.182, "
                   "z: 0.873}' (table4)")
    p.add_argument("--order", default="", metavar="AXES",
                   help="axes (e.g. x,z) on which the paper's order FBC > FBC+FFC > DFBC > "
                   "DFBC+FFC must hold, each at least 1.15 x the next")
    p.add_argument("--order-gap", type=float, default=1.15, metavar="RATIO",
                   help="with --order: least ratio between neighbours (default 1.15; a run's "
                   "scatter needs more the shorter it is)")
    p.add_argument("--corners", action="store_true",
                   help="also tune the feedback high-pass and sensor extension corners")
    p.add_argument("--corner-min", type=float, default=0.02, metavar="HZ",
                   help="with --corners: the lowest corner tried, Hz (how low the sensors can "
                   "be trusted; default 0.02)")
    p.add_argument("--rotations", action="store_true",
                   help="also tune the rotational feedback gains (6dof)")
    p.add_argument("--max-evaluations", type=int, default=300, metavar="N",
                   help="model evaluations at most (default 300)")
    add_margin_options(p)
    p.add_argument("--check-seconds", type=float, default=60.0, metavar="S",
                   help="batch run per mode to check the result (default 60; 0: skip)")
    p.add_argument("--seed", type=int, default=None, metavar="N",
                   help="seed of the batch check (default: the configuration's + 1000, so the "
                   "check never reuses a seed a preset was judged on)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def read_target(path: Path, axes: list[str]) -> dict[str, dict[str, float]]:
    """A target file: mode -> axis -> factor (> 0, finite); Passive, if given, must be 1."""
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"--target {path}: no such file") from None
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"--target {path}: cannot read: {exc}") from None
    if not isinstance(doc, dict) or not doc:
        raise ConfigError(f"--target {path}: expected a mapping mode -> axis -> factor")
    out: dict[str, dict[str, float]] = {}
    for name, row in doc.items():
        try:
            mode = parse_mode(str(name))
        except ModeError as exc:
            raise ConfigError(f"--target {path}: {exc}") from None
        if not isinstance(row, dict) or not row:
            raise ConfigError(f"--target {path}: {name}: expected axis: factor pairs")
        for axis, value in row.items():
            if axis not in axes:
                raise ConfigError(f"--target {path}: {name}.{axis}: the model's table has "
                                  f"axes {', '.join(axes)}")
            if not isinstance(value, (int, float)) or not 0 < value < math.inf:
                raise ConfigError(f"--target {path}: {name}.{axis} = {value!r}: a factor must "
                                  "be a positive number")
            if mode.label == "Passive" and value != 1:
                raise ConfigError(f"--target {path}: Passive is the reference (1 by "
                                  "definition); it cannot be a target")
        if mode.label != "Passive":
            out[mode.label] = {str(a): float(v) for a, v in row.items()}
    if not out:
        raise ConfigError(f"--target {path}: no mode other than Passive")
    return out


def run(args: argparse.Namespace) -> int:
    """Handler of ``tune``."""
    from dcsms_ros.analysis.predict import (  # noqa: PLC0415 - deferred for --help
        predict_table4,
        table_axes,
    )
    from dcsms_ros.core.check import check_config  # noqa: PLC0415 - deferred for --help
    from dcsms_ros.design.tuning import (  # noqa: PLC0415 - deferred for --help
        Problem,
        default_knobs,
        tune,
    )

    if args.out.exists():
        raise DcsmsError(f"--out {args.out}: exists already, not overwriting")
    if not args.out.absolute().parent.is_dir():  # known before the tune, not after it
        raise DcsmsError(f"--out {args.out}: {args.out.absolute().parent} is not a directory")
    if not 10 <= args.max_evaluations <= 100_000:
        raise DcsmsError("--max-evaluations must be in [10, 100000]")
    if not (args.check_seconds >= 0 and math.isfinite(args.check_seconds)):
        raise DcsmsError("--check-seconds must be >= 0")
    cfg = load_cfg(args)
    axes = table_axes(cfg)
    target = read_target(args.target, axes) if args.target is not None else None
    if args.objective == "table4" and target is None:
        raise DcsmsError("--objective table4 needs --target FILE")
    if not 0 < args.corner_min < 1.0:
        raise DcsmsError("--corner-min must be in (0, 1) Hz")
    knobs = default_knobs(cfg, corners=args.corners, rotations=args.rotations,
                          corner_min_hz=args.corner_min)
    order = [a.strip() for a in args.order.split(",") if a.strip()]
    if not args.order_gap >= 1.0:
        raise DcsmsError("--order-gap must be >= 1")
    problem = Problem(cfg, knobs, args.objective, target, args.min_gm, args.min_pm, order,
                      args.order_gap)
    say = (lambda *a: print(*a, file=sys.stderr, flush=True)) if args.json else (
        lambda *a: print(*a, flush=True))
    for knob, value, used in problem.clipped():
        say(f"dcsms tune: {knob.label} = {value:.4g} is outside the searched range "
            f"[{knob.lo:g}, {knob.hi:g}]; the search starts from {used:.4g}")
    start = problem.evaluate(problem.start())
    say(f"dcsms tune: {len(knobs)} knobs ({', '.join(k.label for k in knobs)}), objective "
        f"{args.objective}; start {'feasible' if start.feasible else 'INFEASIBLE'}: "
        f"objective {start.objective:.4g}, worst margin {start.worst_gm_db:.1f} dB / "
        f"{start.worst_pm_deg:.0f} deg, slacks "
        + ", ".join(f"{k} {v:+.3g}" for k, v in start.slacks.items()))

    shown: list[Any] = [None]

    def progress(it: int, ev: Any) -> None:
        # a line when the best candidate changes, else every tenth iteration
        if ev is shown[0] and it % 10:
            return
        shown[0] = ev
        say(f"  iter {it:4d}  evaluations {problem.evaluations:4d}  objective "
            f"{ev.objective:+.4f}  worst margin {ev.worst_gm_db:5.1f} dB / "
            f"{ev.worst_pm_deg:4.0f} deg  {'feasible' if ev.feasible else 'infeasible'}")

    result = tune(problem, args.max_evaluations, progress)
    if not result.evaluation.feasible:
        worst = min(result.evaluation.slacks, key=lambda k: result.evaluation.slacks[k])
        print(f"dcsms tune: no candidate met every constraint after {result.evaluations} "
              f"evaluations (closest: {worst} slack {result.evaluation.slacks[worst]:+.3g}); "
              f"nothing written. Try --corners, lower --min-gm/--min-pm or a stable start.",
              file=sys.stderr)
        return 1
    checks = check_config(result.cfg, min_gm_db=args.min_gm, min_pm_deg=args.min_pm)
    if not all(c.ok for c in checks):
        bad = "; ".join(f"{c.mode.label}: {', '.join(c.failures)}" for c in checks if not c.ok)
        print(f"dcsms tune: the result fails the full check ({bad}); nothing written",
              file=sys.stderr)
        return 1
    predicted = predict_table4(result.cfg)
    simulated = _batch_check(result.cfg, args, axes) if args.check_seconds > 0 else None
    _write(args, cfg.source, result, predicted.values, simulated)
    doc = {"out": str(args.out), "objective": args.objective,
           "objective_value": result.evaluation.objective, "evaluations": result.evaluations,
           "knobs": result.values, "worst_gm_db": result.evaluation.worst_gm_db,
           "worst_pm_deg": result.evaluation.worst_pm_deg, "predicted": predicted.values,
           "simulated": simulated[1] if simulated else None,
           "saturations": simulated[2] if simulated else None, "target": target}
    if args.json:
        print_json(doc)
        return 0
    print(f"dcsms tune: wrote {args.out} after {result.evaluations} evaluations; worst margin "
          f"{result.evaluation.worst_gm_db:.1f} dB / {result.evaluation.worst_pm_deg:.0f} deg")
    for k, v in result.values.items():
        print(f"  {k:<32} {v:.4g}")
    _print_table(axes, predicted.values, simulated, target)
    return 0


def _batch_check(cfg: Any, args: argparse.Namespace, axes: list[str]
                 ) -> tuple[dict[str, float], dict[str, dict[str, float]], int]:
    from dcsms_ros.analysis.batchtable import table4_of_runs  # noqa: PLC0415 - deferred for --help
    from dcsms_ros.core.engine import simulate  # noqa: PLC0415 - deferred for --help

    seed = args.seed if args.seed is not None else cfg.disturbance.seed + 1000
    runs = {m: simulate(cfg, m, args.check_seconds + 1.0, seed=seed) for m in ALL_MODES}
    sat = sum(r.counters["saturations"] for r in runs.values())
    f_r, values = table4_of_runs(runs, axes)
    return f_r, values, sat


def _print_table(axes: list[str], predicted: Mapping[str, Mapping[str, float]],
                 simulated: Any, target: Mapping[str, Mapping[str, float]] | None) -> None:
    cols = ["predicted"] + (["simulated"] if simulated else []) + (["target"] if target else [])
    print(f"{'mode':<10}" + "".join(f"{a.upper() + ' ' + c:>14}" for a in axes for c in cols))
    for mode, row in predicted.items():
        cells = []
        for a in axes:
            cells.append(row[a])
            if simulated:
                cells.append(simulated[1][mode][a])
            if target:
                cells.append(target.get(mode, {}).get(a, math.nan))
        print(f"{mode:<10}" + "".join(f"{x:>14.3f}" if math.isfinite(x) else f"{'-':>14}"
                                      for x in cells))
    if simulated:
        print(f"batch check: {simulated[2]} saturated actuator samples")


def _write(args: argparse.Namespace, source: str, result: Any,
           predicted: Mapping[str, Mapping[str, float]], simulated: Any) -> None:
    from dcsms_ros.core.params_file import params_text  # noqa: PLC0415 - deferred for --help

    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"Written by `dcsms tune --objective {args.objective}` on {when} from {source}",
             (f"({result.evaluations} model evaluations on the loop as it runs; every mode "
              f"stable, margins >= {args.min_gm:g} dB / {args.min_pm:g} deg, force RMS <= "
              f"limit/4)."),
             "Tuned: " + ", ".join(f"{k} = {v:.4g}" for k, v in result.values.items()),
             "Predicted Table 4: " + "; ".join(
                 f"{m} " + " ".join(f"{a}={v:.3f}" for a, v in row.items())
                 for m, row in predicted.items())]
    if simulated:
        lines.append(f"Batch check ({args.check_seconds:g} s per mode): " + "; ".join(
            f"{m} " + " ".join(f"{a}={v:.3f}" for a, v in row.items())
            for m, row in simulated[1].items()) + f"; {simulated[2]} saturated samples")
    header = "".join(f"# {line}\n" for line in lines)
    tmp = args.out.with_name(args.out.name + ".partial")
    assert result.cfg.params is not None
    tmp.write_text(header + params_text(result.cfg.params))
    tmp.replace(args.out)


__all__ = ["read_target", "register", "run"]
