"""``dcsms params``: the parameter table and docs/parameters.md generated from it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dcsms_ros.cli import main
from dcsms_ros.cli.params import BEGIN, END, markdown, rows
from dcsms_ros.core.schema import BODY_SPECS, GLOBAL_SPECS, STAGE_SPECS

PARAMETERS_DOC = Path(__file__).resolve().parents[2] / "docs" / "parameters.md"


def test_markdown_table(capsys: pytest.CaptureFixture[str]) -> None:
    """params --markdown is a table with one row per schema entry, units included."""
    assert main(["params", "--markdown"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("| name | type | unit |")
    assert "| `<stage>.mass` | float | kg | 988.8 (stage2: 748.8) |" in out
    assert out.count("\n| `") == len(GLOBAL_SPECS) + len(BODY_SPECS) + len(STAGE_SPECS)


def test_json_rows(capsys: pytest.CaptureFixture[str]) -> None:
    """params --json lists name, unit, default, range and description of every parameter."""
    assert main(["params", "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    rate = next(r for r in table if r["name"] == "plant.rate_hz")
    assert rate["unit"] == "Hz" and rate["range"] == "[10, 100000]"


def test_parameter_doc_is_current() -> None:
    """docs/parameters.md's table equals the schema (regenerate: dcsms params --markdown --into
    docs/parameters.md)."""
    text = PARAMETERS_DOC.read_text()
    inner = text.split(BEGIN, 1)[1].split(END, 1)[0]
    assert inner.strip() == markdown(rows()).strip()


def test_into_replaces_between_markers(capsys: pytest.CaptureFixture[str],
                                       tmp_path: Path) -> None:
    """--into rewrites only the marked section; a file without markers is an error (exit 2)."""
    doc = tmp_path / "doc.md"
    doc.write_text(f"intro\n{BEGIN}\nSTALE TABLE\n{END}\noutro\n")
    assert main(["params", "--markdown", "--into", str(doc)]) == 0
    text = doc.read_text()
    assert text.startswith("intro\n") and text.endswith("outro\n") and "STALE" not in text
    doc.write_text("no markers")
    assert main(["params", "--markdown", "--into", str(doc)]) == 2
    assert "markers" in capsys.readouterr().err
