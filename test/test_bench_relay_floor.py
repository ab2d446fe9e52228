"""`bench/relay_floor.py`: a Python relay woken by a FIFO write, on two cores and on one."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("relay_floor", ROOT / "bench" / "relay_floor.py")
assert _spec is not None and _spec.loader is not None
relay_floor = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(relay_floor)


@pytest.mark.parametrize("placement", ["spread", "one core"])
def test_every_frame_is_relayed_and_each_process_spends_cpu_per_message(placement: str) -> None:
    """0.4 s at 2 kHz, default scheduler: the relay passes on all 800 frames, and each of the
    three processes spends a positive CPU time per message, at most the period (500 us)."""
    cores = sorted(os.sched_getaffinity(0))
    other = cores[-2] if placement == "spread" and len(cores) > 1 else cores[-1]
    r = relay_floor.measure(0.4, 0, cores[-1], other)
    assert r["relayed"] == 800 and r["fifo"] is False
    for key in ("relay_us", "writer_us", "sink_us"):
        assert 0.0 < r[key] < 500.0
