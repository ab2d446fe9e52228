"""Turn the reliability tests' results (JSON lines) into the table of docs/reliability.md.

    python test/reliability/make_table.py [RESULTS.jsonl] [--into docs/reliability.md]

RESULTS defaults to ``$DCSMS_RELIABILITY_RESULTS`` or the tests' default file; the newest line
of each row wins. ``--into`` replaces the text between the markers below in that file.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from rel_harness import results_file

from dcsms_ros.errors import DcsmsError
from dcsms_ros.markers import replace_between_markers

BEGIN = "<!-- reliability table: begin -->"
END = "<!-- reliability table: end -->"


def _key(row: str) -> tuple[int, str]:
    m = re.match(r"(\d+)(.*)", row)
    return (int(m.group(1)), m.group(2)) if m else (99, row)


def table(path: Path) -> str:
    """The newest result of each row as a Markdown table (fault, result, figure)."""
    rows: dict[str, dict] = {}
    for line in path.read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            rows[r["row"]] = r
    out = ["| # | fault | result | figure |", "|---|---|---|---|"]
    for key in sorted(rows, key=_key):
        r = rows[key]
        cells = [key, r["fault"], r["result"], r["figure"]]
        out.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="?", type=Path, default=None)
    p.add_argument("--into", type=Path, default=None, metavar="FILE")
    a = p.parse_args(argv)
    text = table(a.results or results_file())
    if a.into is None:
        print(text)
        return 0
    try:
        replace_between_markers(a.into, text, BEGIN, END)
    except DcsmsError as exc:
        print(f"make_table: error: {exc}", file=sys.stderr)
        return 2
    print(f"updated {a.into}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
