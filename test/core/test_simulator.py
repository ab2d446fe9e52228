"""PlantSimulator.advance: the controllers' wrenches summed per stage, bad ones refused."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from dcsms_ros.core.config import load_config
from dcsms_ros.core.simulator import PlantSimulator

CONFIG = Path(__file__).resolve().parents[2] / "config"


@pytest.fixture(params=["table1.yaml", "tem_three_point.yaml"])
def sim_pair(request: pytest.FixtureRequest) -> tuple[PlantSimulator, PlantSimulator]:
    cfg = load_config(CONFIG / request.param)
    return PlantSimulator(cfg, seed=7), PlantSimulator(cfg, seed=7)


def test_two_controllers_on_a_stage_act_as_their_sum(
        sim_pair: tuple[PlantSimulator, PlantSimulator]) -> None:
    """fb_stage1 and ff_stage1 both act on stage 1: the plant applies w1 + w2 (0 + w1 + w2 is
    that sum to the bit), and fb_stage2 on stage 2 alone."""
    a, b = sim_pair
    rng = np.random.default_rng(3)
    for _ in range(20):
        w1, w2, w3 = (rng.normal(scale=0.05, size=a.dof) for _ in range(3))
        got = a.advance({"fb_stage1": w1, "ff_stage1": w2, "fb_stage2": w3})
        want = b.advance({"fb_stage1": w1 + w2, "fb_stage2": w3})
        assert_array_equal(got, want)
        assert_array_equal(a.measure(), b.measure())


def test_a_nonfinite_wrench_counts_as_zero(
        sim_pair: tuple[PlantSimulator, PlantSimulator]) -> None:
    a, b = sim_pair
    w = np.full(a.dof, 0.01)
    bad = w.copy()
    bad[-1] = np.nan
    assert_array_equal(a.advance({"fb_stage1": bad, "fb_stage2": w}),
                       b.advance({"fb_stage2": w}))
    assert a.nonfinite_inputs == 1 and b.nonfinite_inputs == 0


def test_a_wrench_of_the_wrong_length_is_refused(
        sim_pair: tuple[PlantSimulator, PlantSimulator]) -> None:
    a, _ = sim_pair
    with pytest.raises(ValueError, match="fb_stage1: wrench of 2 components"):
        a.advance({"fb_stage1": np.zeros(2)})
