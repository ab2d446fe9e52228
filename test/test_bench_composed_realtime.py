"""`bench/composed_realtime.py`: repeated runs pooled as one long run would count them."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

# the bench's own modules are not a package: imported from its directory
import composed_realtime
from graph_run import realtime_stats

RATE = 2000.0


def _run(seed: int, n: int, late: int, stale: int, overruns: int = 0) -> dict[str, Any]:
    """A real-time run as ``graph_run.run_graph`` returns it: publication times with jitter
    and one long period, three controllers' latencies, the counts."""
    rng = np.random.default_rng(seed)
    periods = 1.0 / RATE + rng.normal(0.0, 2e-5, n - 1)
    periods[n // 2] = 3.0 / RATE  # a late period
    t = 100.0 * seed + np.concatenate([[0.0], np.cumsum(periods)])
    return {"t": t, "rate_hz": RATE, "cpu": {"composed": 0.5 + 0.01 * seed, "driver": 0.45},
            "latency_s": rng.uniform(5e-5, 4e-4, 3 * n), "overruns": overruns, "late": late,
            "stale": stale, "controllers": 3}


def test_one_run_pooled_is_that_run() -> None:
    r = _run(1, 4000, late=3, stale=1)
    r_all, s_all = composed_realtime.pooled([r])
    s = realtime_stats(r)
    for key in ("rate_hz", "p50", "p99", "p999", "max", "miss", "lat50", "lat99", "samples"):
        assert_allclose(s_all[key], s[key], rtol=1e-12, err_msg=key)
    assert (r_all["late"], r_all["stale"], r_all["overruns"]) == (3, 1, 0)


def test_runs_pool_their_periods_counts_and_latencies() -> None:
    runs = [_run(1, 4000, 3, 0), _run(2, 6000, 0, 5, overruns=2)]
    r_all, s_all = composed_realtime.pooled(runs)
    periods = np.concatenate([np.diff(r["t"][10:]) for r in runs])
    assert s_all["samples"] == 4000 - 10 + 6000 - 10
    assert_allclose(s_all["miss"], np.mean(periods > 1.5 / RATE))
    assert_allclose(s_all["rate_hz"], periods.size / periods.sum())
    assert_allclose(s_all["lat99"], np.percentile(np.concatenate([r["latency_s"] for r in runs]),
                                                  99))
    assert (r_all["late"], r_all["stale"], r_all["overruns"]) == (3, 5, 2)
    assert_allclose(r_all["cpu"]["composed"], 0.515)


@pytest.mark.parametrize(("late", "stale", "overruns", "want"),
                         [(0, 0, 0, 0.0), (40, 0, 0, 1e-3), (20, 60, 0, 5e-4 + 5e-4),
                          (38, 0, 2, 38 / 40002)])
def test_late_fraction_counts_every_passed_deadline(late: int, stale: int, overruns: int,
                                                    want: float) -> None:
    r = _run(3, 100, late, stale, overruns)
    x, deadlines, forces = composed_realtime.late_fraction(r, 40000)
    assert (deadlines, forces) == (40000 + overruns, 120000)
    assert_allclose(x, want)


def poisson_interval(k: int) -> tuple[float, float]:
    """The 95 % interval of a Poisson mean after ``k`` events, by bisection on the
    cumulative probabilities (independent of the chi-square form the bench uses)."""
    def cdf(m: float, j: int) -> float:
        return sum(math.exp(-m + i * math.log(m) - math.lgamma(i + 1)) for i in range(j + 1))

    def solve(f: Any, a: float, b: float) -> float:
        for _ in range(200):
            c = (a + b) / 2
            a, b = (c, b) if f(c) > 0 else (a, c)
        return (a + b) / 2

    lo = 0.0 if k == 0 else solve(lambda m: cdf(m, k - 1) - 0.975, 1e-9, 10.0 * k + 10)
    hi = solve(lambda m: cdf(m, k) - 0.025, 1e-9, 10.0 * k + 10)
    return lo, hi


@pytest.mark.parametrize("k, n", [(0, 1000), (1, 1000), (42, 8000), (160, 160000)])
def test_count_interval_is_the_exact_poisson_interval(k: int, n: int) -> None:
    lo, hi = composed_realtime.count_interval(k, n)
    assert_allclose((lo * n, hi * n), poisson_interval(k), rtol=1e-6, atol=1e-9)
    assert lo <= k / n <= hi


def test_rows_pool_the_runs_and_count_those_within_the_target() -> None:
    """The late row's value is the pooled rate (not a mean of the runs' rates), its note names
    each run and how many met 1e-3; the floor row pools its runs the same way."""
    secs = 2.0
    runs = [_run(1, 4000, late=2, stale=0), _run(2, 4000, late=40, stale=3)]
    runs[1]["woke_late"] = 30
    runs[0]["paused"], runs[1]["paused"] = 1, 4
    floors = [{"late": 1, "samples": 4000, "late_ratio": 2.5e-4, "work_us": 230.0,
               "wake_us": [40.0, 60.0, 150.0]},
              {"late": 9, "samples": 4000, "late_ratio": 2.25e-3, "work_us": 240.0,
               "wake_us": [40.0, 60.0, 150.0]}]
    idle = {"late": 0, "samples": 4000, "late_ratio": 0.0}

    def realtime_rows(r: dict[str, Any], s: dict[str, float], seconds: float,
                      label: str) -> list[dict[str, Any]]:
        return [{"name": f"rate {seconds:g}{label}"}, {"name": "miss"}, {"name": "latency"}]

    rows = composed_realtime.rows(secs, runs, floors, idle, "recorded", None, realtime_rows)
    assert rows[0]["name"] == "rate 4, composed, recorder in the process"
    late, floor = rows[1], rows[2]
    assert_allclose(late["value"], 42 / 8000 + 3 / 24000)
    assert "within 0.001 in 1 of 2" in late["note"] and "NOT met" in late["note"]
    assert "0.00050 / 0.01025" in late["note"]
    # 30 of the 42 late passed while nothing of the process ran after a wake-up, 5 were
    # pushed back by a pause while the driver worked; the rest with the stale forces
    assert ("of the late, 30 passed while the driver, asleep until its next deadline, was not "
            "run after its wake-up time and nothing of its process ran, and 5 more were pushed "
            "back by such a pause while it worked") in late["note"]
    assert f"with the stale forces: {7 / 8000 + 3 / 24000:.5f}" in late["note"]
    lo, hi = (x / 8000 + 3 / 24000 for x in poisson_interval(42))
    assert f"interval of the pooled figure {lo:.5f}-{hi:.5f}" in late["note"]
    assert_allclose(floor["value"], 10 / 8000)
    assert_allclose(late["baseline"], floor["value"])
    assert floor["baseline"] == 0.0
