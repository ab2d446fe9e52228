"""`bench/timer_floor.py`: the ideal periodic worker counts late samples as the graph does; a
pause the OS makes is charged nothing to a spinning thread (``--charged``)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("timer_floor", ROOT / "bench" / "timer_floor.py")
assert _spec is not None and _spec.loader is not None
timer_floor = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(timer_floor)


def test_a_worker_longer_than_the_period_is_late_on_every_sample() -> None:
    """600 us of work per 500 us sample: each sample ends after the next deadline, and the
    skipped deadlines count too, so every one of the samples is late."""
    r = timer_floor.measure(0.2, 600.0, rt_priority=0)
    assert r["samples"] == 400 and r["late"] == 400 and r["late_ratio"] == 1.0


@pytest.mark.parametrize("work_us", [0.0, 100.0])
def test_a_short_worker_wakes_after_its_deadlines(work_us: float) -> None:
    """Well under the period: the wake-up quantiles are ordered, non-negative (never before
    a deadline) and the late count a fraction of the samples."""
    r = timer_floor.measure(0.5, work_us, rt_priority=0)
    p50, p99, p999 = r["wake_us"]
    assert 0.0 <= p50 <= p99 <= p999
    assert r["samples"] == 1000 and 0 <= r["late"] < r["samples"]
    assert r["fifo"] is False and r["latency_held"] is None


def test_a_stopped_process_s_gap_is_not_charged_to_its_spinning_thread(process_pause) -> None:
    """A whole-process stop (SIGSTOP) takes the thread off its core: the gap is charged
    nothing, so a gap charged in full is one the hypervisor made while the thread ran."""
    span = process_pause(0.1, 0.05)
    out = timer_floor.charged_gaps(0.4)
    p0, p1 = span()
    stop = [(w, c) for w, c in out["gaps"] if w >= (p1 - p0) * 1e6 - 5000]
    assert stop, (out, p1 - p0)
    assert all(c < 0.2 * w for w, c in stop), stop
