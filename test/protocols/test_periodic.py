"""Periodic schedule: many job periods on one tick, each job at its own rate, staggered."""

from __future__ import annotations

import random
from collections import Counter

import pytest

from dcsms_ros.protocols.periodic import PeriodicSchedule

# the composed graph's housekeeping: the judge 20 Hz, reports 1 Hz, reconcile and discovery
# 2 Hz, the recorder's flush 4 Hz
PERIODS = [0.05, 1.0, 1.0, 1.0, 0.5, 0.5, 0.25, 1.0, 1.0, 1.0]


def _run(sched: PeriodicSchedule, seconds: float, jitter_s: float = 0.0,
         seed: int = 1) -> tuple[Counter[int], list[list[int]]]:
    rng = random.Random(seed)
    runs: Counter[int] = Counter()
    ticks = []
    n = int(round(seconds / sched.tick_s))
    for i in range(1, n + 1):
        due = sched.due(i * sched.tick_s + rng.uniform(0.0, jitter_s))
        runs.update(due)
        ticks.append(due)
    return runs, ticks


@pytest.mark.parametrize("jitter_s", [0.0, 0.004, 0.02])
def test_every_job_runs_at_its_own_rate(jitter_s: float) -> None:
    """Over 100 s each job ran 100 s / period times (+-1 for the last partial period), even
    with tick jitter up to 40 % of the tick."""
    sched = PeriodicSchedule(PERIODS, 0.0)
    assert sched.tick_s == 0.05
    runs, _ = _run(sched, 100.0, jitter_s)
    for j, p in enumerate(PERIODS):
        assert abs(runs[j] - 100.0 / p) <= 1, (j, p, runs[j])
    assert sched.skipped == [0] * len(PERIODS)


def test_slower_jobs_are_staggered_across_ticks() -> None:
    """No tick runs more than the fastest job and one other (there are fewer slow jobs than
    ticks per second), and each slow job keeps its own tick phase."""
    sched = PeriodicSchedule(PERIODS, 0.0)
    _, ticks = _run(sched, 20.0)
    assert max(len(t) for t in ticks) == 2
    assert all(0 in t for t in ticks)  # the 20 Hz job runs on every tick
    phases = {j: {i % round(PERIODS[j] / 0.05) for i, t in enumerate(ticks) if j in t}
              for j in range(1, len(PERIODS))}
    assert all(len(ph) == 1 for ph in phases.values())
    assert len({(round(PERIODS[j] / 0.05), next(iter(ph))) for j, ph in phases.items()}) == \
        len(phases)


def test_a_job_that_fell_behind_skips_instead_of_bursting() -> None:
    sched = PeriodicSchedule([0.05, 0.5], 0.0)
    assert sched.due(0.05) == [0]
    assert sched.offsets == [0.0, 0.0]
    assert sched.due(3.0) == [0, 1]  # after a 3 s stall, once each
    assert sched.skipped == [58, 5]  # 0.15 ... 3.0 and 1.0 ... 3.0 (the run at 3.0 is 0.1's, 0.5's)
    assert sched.due(3.05) == [0]
    assert sched.due(3.5) == [0, 1]  # on its phase: n * 0.5


def test_periods_must_be_positive() -> None:
    with pytest.raises(ValueError, match="positive"):
        PeriodicSchedule([0.05, 0.0], 0.0)
    with pytest.raises(ValueError, match="positive"):
        PeriodicSchedule([], 0.0)
