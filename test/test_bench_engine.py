"""`bench/engine_bench.py`: why the engine row misses, from its same-run baseline."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

# the bench's own modules are not a package: imported from its directory
import engine_bench


def test_a_met_row_has_no_reason() -> None:
    assert engine_bench._why_slow(120.0, 5.0, 100.0) == ""


@pytest.mark.parametrize(("fast", "slow"), [(98.3, 4.68), (60.0, 6.0)])
def test_a_missed_row_names_the_baseline_the_target_needs_at_its_ratio(fast: float,
                                                                       slow: float) -> None:
    """At the row's ratio to its baseline, the baseline the target needs: ``target / ratio``
    (98.3 against 4.68: 21.0x, so 4.76 sim s / wall s)."""
    why = engine_bench._why_slow(fast, slow, 100.0)
    assert why.startswith("; NOT met on this host")
    ratio = float(re.search(r"ran ([\d.]+)x", why).group(1))
    need = float(re.search(r"run ([\d.]+) or more", why).group(1))
    assert ratio == pytest.approx(fast / slow, abs=0.05)
    assert need == pytest.approx(100.0 * slow / fast, rel=2e-3)
