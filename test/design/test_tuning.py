"""The tuner's judgement equals the model check's, and its search keeps every constraint."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from dcsms_ros.analysis.predict import predict_table4, table_axes
from dcsms_ros.core.check import check_config, stability
from dcsms_ros.core.config import load_config
from dcsms_ros.core.margins import frequency_grid
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.safety import MIN_GM_DB, MIN_PM_DEG
from dcsms_ros.design.tuning import Knob, Problem, default_knobs, judge, tune

ROOT = Path(__file__).resolve().parents[2]
TABLE1 = ROOT / "config" / "table1.yaml"
FIXTURE = ROOT / "test" / "fixtures" / "tem_unstable.yaml"


@pytest.mark.parametrize("knob", [Knob("feedback.stage1.gain", 2, 10.0, 1e6),
                                  Knob("feedforward.gain", -1, 0.0, 1.05, log=False)],
                         ids=["log", "linear"])
def test_unit_coordinates_round_trip(knob):
    for value in (knob.lo, knob.hi, 0.3 * knob.lo + 0.7 * knob.hi):
        u = knob.to_unit(value)
        assert 0.0 <= u <= 1.0
        assert knob.from_unit(u) == pytest.approx(value, rel=1e-12)


def test_judge_calls_the_unstable_fixture_unstable_at_the_models_growth():
    """The stability slack is minus the worst growth rate (1/s) of the model check's poles."""
    cfg = load_config(FIXTURE)
    ev = judge(cfg, table_axes(cfg), ["DFBC+FFC"], "attenuation", {}, MIN_GM_DB, MIN_PM_DEG,
               frequency_grid(cfg.plant.rate_hz, 300))
    assert not ev.feasible
    assert ev.slacks["stable"] == pytest.approx(-stability(cfg, Mode.DFBC).growth_per_s,
                                                rel=1e-9)


def test_judge_of_a_preset_matches_the_check_and_the_prediction():
    """Table 1 passes the check; judge finds it feasible with the check's margins and the
    predicted Table 4 (band integration on fewer points: 1 %)."""
    cfg = load_config(TABLE1)
    assert all(c.ok for c in check_config(cfg))
    ev = judge(cfg, ["z"], ["FBC", "DFBC+FFC"], "attenuation", {}, MIN_GM_DB, MIN_PM_DEG)
    assert ev.feasible and ev.worst_gm_db >= MIN_GM_DB and ev.worst_pm_deg >= MIN_PM_DEG
    pred = predict_table4(cfg).values
    for m in ("FBC", "DFBC+FFC"):
        assert ev.table[m]["z"] == pytest.approx(pred[m]["z"], rel=0.01)
    assert ev.objective == pytest.approx(math.log(ev.table["DFBC+FFC"]["z"]), rel=1e-9)


@pytest.mark.slow
def test_attenuation_search_improves_and_keeps_every_constraint():
    """From Table 1's gains, 40 evaluations lower DFBC+FFC; the result passes the full check."""
    cfg = load_config(TABLE1)
    problem = Problem(cfg, default_knobs(cfg), "attenuation")
    start = problem.evaluate(problem.start())
    result = tune(problem, max_evaluations=40)
    assert problem.evaluations <= 1 + 40  # the start, then the budget
    assert result.evaluation.feasible
    assert result.evaluation.objective < start.objective - 0.05
    assert all(c.ok for c in check_config(result.cfg))
    for k in problem.knobs:
        assert k.lo <= result.values[k.label] <= k.hi
    assert predict_table4(result.cfg).values["DFBC+FFC"]["z"] == pytest.approx(
        math.exp(result.evaluation.objective), rel=0.01)


@pytest.mark.slow
def test_table4_search_moves_towards_the_target():
    """A target 1.6x Table 1's FBC and DFBC values in Z: the squared log error shrinks."""
    cfg = load_config(TABLE1)
    pred = predict_table4(cfg).values
    target = {"FBC": {"z": 1.6 * pred["FBC"]["z"]}, "DFBC": {"z": 1.6 * pred["DFBC"]["z"]}}
    problem = Problem(cfg, default_knobs(cfg), "table4", target)
    start = problem.evaluate(problem.start())
    assert start.objective == pytest.approx(2 * math.log(1.6) ** 2, rel=0.02)
    result = tune(problem, max_evaluations=40)
    assert result.evaluation.feasible
    assert result.evaluation.objective < 0.25 * start.objective
    got = predict_table4(result.cfg).values
    for m, row in target.items():
        assert abs(math.log(got[m]["z"] / row["z"])) < 0.5 * math.log(1.6)


def test_order_constraint_is_a_slack_per_axis():
    """--order z adds one slack: the least ln ratio of neighbours minus ln 1.15."""
    cfg = load_config(TABLE1)
    problem = Problem(cfg, default_knobs(cfg), "attenuation", order=["z"])
    ev = problem.evaluate(problem.start())
    rows = [ev.table[m]["z"] for m in ("FBC", "FBC+FFC", "DFBC", "DFBC+FFC")]
    expect = min(np.log(np.array(rows[:-1]) / np.array(rows[1:]))) - math.log(1.15)
    assert ev.slacks["order z"] == pytest.approx(expect, rel=1e-9)


def test_a_start_outside_the_range_is_reported():
    """High-pass corners of 0.032 / 0.035 Hz lie below --corner-min 0.05: the problem names
    both and starts them at 0.05 Hz."""
    cfg = load_config(ROOT / "config" / "tem_three_point.yaml",
                      {"feedback.stage1.highpass_hz": 0.032, "feedback.stage2.highpass_hz": 0.035})
    problem = Problem(cfg, default_knobs(cfg, corners=True, corner_min_hz=0.05), "attenuation")
    got = {k.label: (v, used) for k, v, used in problem.clipped()}
    assert got == {"feedback.stage1.highpass_hz": (pytest.approx(0.032), pytest.approx(0.05)),
                   "feedback.stage2.highpass_hz": (pytest.approx(0.035), pytest.approx(0.05))}
