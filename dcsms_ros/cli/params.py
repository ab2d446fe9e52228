"""``dcsms params``: every configurable parameter with unit, default, range and meaning.

``--markdown`` prints the table that docs/parameters.md is generated from.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import print_json
from dcsms_ros.core.schema import (
    BODY_SPECS,
    GLOBAL_SPECS,
    STAGE_DEFAULTS,
    STAGE_SPECS,
    ParamSpec,
)
from dcsms_ros.errors import DcsmsError
from dcsms_ros.markers import replace_between_markers

#: Markers around the generated table in docs/parameters.md.
BEGIN = "<!-- dcsms params --markdown: begin -->"
END = "<!-- dcsms params --markdown: end -->"


def register(subparsers: Any) -> None:
    """Add the ``params`` sub-command."""
    p = subparsers.add_parser(
        "params", help="list every configuration parameter",
        description="List every parameter of the config files (ROS 2 params YAML): dotted "
        "name, SI unit, default, valid range and meaning. <stage> is stage1 ... stageN, "
        "<body> is ground or a stage.")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--markdown", action="store_true", help="print a Markdown table")
    fmt.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--into", type=Path, metavar="FILE", default=None,
                   help=f"with --markdown: replace the text between '{BEGIN}' and '{END}' in "
                   "FILE (docs/parameters.md) instead of printing")
    p.set_defaults(func=run)


def rows() -> list[dict[str, str]]:
    """One row per parameter template, in schema order (global, body, stage)."""
    out = []
    for spec in (*GLOBAL_SPECS, *BODY_SPECS, *STAGE_SPECS):
        name = spec.name.replace("{s}", "<stage>").replace("{b}", "<body>")
        out.append({
            "name": name,
            "type": _kind(spec),
            "unit": spec.unit,
            "default": _default(spec),
            "range": _range(spec),
            "fidelity": spec.fidelity or "both",
            "description": spec.doc,
        })
    return out


def _kind(spec: ParamSpec) -> str:
    if spec.kind in ("floats", "ints"):
        item = spec.kind[:-1]
        if spec.length > 0:
            return f"{item}[{spec.length}]"
        return f"{item}[3n]" if spec.length == -3 else f"{item}[]"
    return spec.kind


def _fmt(x: Any) -> str:
    if isinstance(x, bool):
        return str(x).lower()
    if isinstance(x, float):
        return f"{x:g}"
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in x) + "]"
    return str(x)


def _default(spec: ParamSpec) -> str:
    text = _fmt(spec.default)
    if "{s}" in spec.name:
        suffix = spec.name.replace("{s}", "")
        extra = [f"{k.split('.')[0]}: {_fmt(v)}" for k, v in STAGE_DEFAULTS.items()
                 if k.endswith(suffix) and k.replace(suffix, "").startswith("stage")]
        if extra:
            text += " (" + ", ".join(extra) + ")"
    return text


def _range(spec: ParamSpec) -> str:
    if spec.choices:
        return " / ".join(spec.choices)
    if spec.kind in ("str", "bool"):
        return ""
    if math.isinf(spec.lo) and math.isinf(spec.hi):
        return "any"
    num = (lambda x: str(int(x))) if spec.kind in ("int", "ints") else (lambda x: _fmt(float(x)))
    lo = "(" if spec.lo_open else "["
    hi = "inf)" if math.isinf(spec.hi) else f"{num(spec.hi)}]"
    lo_text = "-inf" if math.isinf(spec.lo) else num(spec.lo)
    return f"{lo}{lo_text}, {hi}"


def markdown(table: list[dict[str, str]]) -> str:
    """The rows as a GitHub Markdown table (pipes in cells escaped)."""
    cols = ("name", "type", "unit", "default", "range", "fidelity", "description")
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in table:
        cells = [r[c].replace("|", "\\|") for c in cols]
        cells[0] = f"`{cells[0]}`"
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Print the parameter table in the chosen format."""
    table = rows()
    if args.into is not None:
        if not args.markdown:
            raise DcsmsError("--into needs --markdown")
        replace_between_markers(args.into, markdown(table), BEGIN, END)
        print(f"updated {args.into}")
        return 0
    if args.json:
        print_json(table)
    elif args.markdown:
        print(markdown(table))
    else:
        width = max(len(r["name"]) for r in table)
        for r in table:
            print(f"{r['name']:<{width}}  {r['default']:<24} {r['unit']:<14} {r['range']}")
            print(f"{'':<{width}}    {r['description']} [{r['type']}, {r['fidelity']}]")
    return 0
