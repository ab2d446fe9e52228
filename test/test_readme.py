"""The README stays a newcomer's page: what, quick start, graph table, CLI tour."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_readme_is_at_most_15_kb_and_names_the_test_command() -> None:
    """Measurement logs and experiment tables belong in docs/: the page stays within 15,000
    bytes, and it names `make test`, the command CI runs (`.ci/run`)."""
    text = (ROOT / "README.md").read_bytes()
    assert len(text) <= 15_000, f"README.md is {len(text)} bytes"
    assert b"make test" in text
    assert "make test" in (ROOT / ".ci" / "run").read_text()
