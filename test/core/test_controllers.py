"""Fader, Allocator, feedback and feedforward loops (fade, saturation, anti-windup, faults)."""

from __future__ import annotations

import copy
import math
import pickle
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from sixdof_helper import sixdof_config

from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.controllers import (
    Allocator,
    Fader,
    FeedbackLoop,
    FeedforwardLoop,
    make_controller,
    suspension_totals,
)
from dcsms_ros.core.filters import feedback_tf, feedforward_tf
from dcsms_ros.errors import ConfigError

FS = 2000.0
TEM = Path(__file__).resolve().parents[2] / "config" / "tem_paper_fit.yaml"


def cresp(tf, f_hz):
    s = 2j * np.pi * np.asarray(f_hz, float)
    return np.polyval(tf.num, s) / np.polyval(tf.den, s)


def sine_gain(loop, f0, amp, axis=0, n=12000, dof=1):
    """Complex steady-state gain of loop output / sine input on ``axis`` (last 0.5 s)."""
    t = np.arange(n) / FS
    x = np.zeros((n, dof))
    x[:, axis] = amp * np.sin(2 * math.pi * f0 * t)
    y = np.array([loop.step(row) for row in x])
    tail = slice(n - 1000, n)
    ph = 2 * math.pi * f0 * t[tail]
    basis = np.column_stack([np.sin(ph), np.cos(ph)])
    coef, *_ = np.linalg.lstsq(basis, y[tail], rcond=None)
    return (coef[0] + 1j * coef[1]) / amp, y


@pytest.mark.parametrize(("fade_s", "steps"), [(0.01, 20), (0.0025, 5)])
def test_fader_linear_ramp(fade_s, steps):
    """The gain ramps linearly k/N up and back down over fade_time."""
    f = Fader(fade_s, 1 / FS)
    f.set_target(True)
    up = [f.step() for _ in range(steps + 3)]
    assert_allclose(up, [min(k, steps) / steps for k in range(1, steps + 4)], rtol=0, atol=0)
    f.set_target(False)
    down = [f.step() for _ in range(steps + 1)]
    assert_allclose(down, [max(steps - k, 0) / steps for k in range(1, steps + 2)])


def test_fader_instant():
    """fade_time 0 switches in one sample."""
    f = Fader(0.0, 1 / FS)
    assert f.step() == 0.0
    f.set_target(True)
    assert f.step() == 1.0 and f.value == 1.0


def test_allocator_round_trip_and_clip_6dof():
    """pinv allocation reproduces the wrench; clipping counts saturated actuators."""
    al = Allocator(sixdof_config(), 1)
    w = np.array([10.0, -5.0, 40.0, 2.0, -3.0, 1.0])
    assert_allclose(al.wrench(al.forces(w)), w, rtol=1e-12, atol=1e-12)
    clipped, n = al.clip(np.array([150.0, -120.0, 10.0, 0.0, 99.0, -100.0]))
    assert n == 2 and al.limit == 100.0
    assert_allclose(clipped, [100.0, -100.0, 10.0, 0.0, 99.0, -100.0])


def test_allocator_1dof_lumped_limit():
    """1dof: one lumped channel with limit count*force_limit."""
    al = Allocator(load_config(), 2)
    assert al.n_act == 1 and al.limit == 400.0
    assert_allclose(al.forces([5.0]), [5.0])


@pytest.mark.parametrize("make", [lambda: Allocator(sixdof_config(), 1),
                                  lambda: Allocator(sixdof_config(), 2),
                                  lambda: Allocator(load_config(), 1),
                                  lambda: Allocator(load_config(TEM), 2)])
def test_a_wrench_within_the_safe_bound_saturates_no_actuator(make):
    """``safe_wrench`` (the loops skip the allocation below it) is a true bound: 10,000 random
    wrenches no larger in any component never saturate, and it is tight: the worst wrench at
    the bound drives one actuator to its limit (within 1e-6), 0.1 % more saturates it."""
    al = make()
    rng = np.random.default_rng(7)
    dof = al.b.shape[0]
    for w in rng.uniform(-1.0, 1.0, (10_000, dof)) * al.safe_wrench:
        assert al.clip(al.forces(w))[1] == 0
    i = int(np.argmax(np.abs(al.pinv).sum(axis=1)))
    worst = np.sign(al.pinv[i]) * al.safe_wrench  # every component adds to actuator i
    assert al.clip(al.forces(worst))[1] == 0
    assert abs(al.forces(worst)[i]) == pytest.approx(al.limit, rel=1e-6)
    assert al.clip(al.forces(worst * 1.001))[1] >= 1


@pytest.mark.parametrize("f0", [2.0, 5.0, 20.0, 60.0])
def test_feedback_sine_response_equals_minus_tf(f0):
    """Steady-state sine response of FeedbackLoop equals -feedback_tf (magnitude and phase)."""
    cfg = load_config()
    g, _ = sine_gain(FeedbackLoop(cfg, 1, enabled=True), f0, 1e-5)
    expected = -cresp(feedback_tf(cfg.feedback[0], 2), f0)
    assert_allclose(abs(g[0]), abs(expected), rtol=5e-3)
    assert abs(np.angle(g[0] / expected, deg=True)) < 0.5


def test_feedforward_sine_response_1dof():
    """FeedforwardLoop follows -feedforward_tf with the stage-1 c1, k1."""
    cfg = load_config()
    g, _ = sine_gain(FeedforwardLoop(cfg, enabled=True), 8.0, 1e-6)
    expected = -cresp(feedforward_tf(cfg.feedforward, 1960.0, 1.2e6), 8.0)
    assert_allclose(g[0], expected, rtol=5e-3)


def test_feedforward_6dof_axes_use_mount_totals():
    """6dof feedforward acts on x, y, z with per-axis mount sums and no moments."""
    cfg = sixdof_config()
    ff = FeedforwardLoop(cfg, enabled=True)
    assert sorted(ff.tfs) == [0, 1, 2]
    assert_allclose(suspension_totals(cfg, 1), [(600.0, 3e5), (900.0, 4.5e5), (1950.0, 1.2e6)])
    g, y = sine_gain(ff, 8.0, 1e-6, axis=1, n=6000, dof=6)
    assert_allclose(g[1], -cresp(feedforward_tf(cfg.feedforward, 900.0, 4.5e5), 8.0), rtol=5e-3)
    assert np.all(y[:, [0, 2, 3, 4, 5]] == 0.0)


def test_fade_in_scales_output_linearly():
    """After enable(True) the output is (k/N) times the always-on output: no cold start."""
    cfg = with_overrides(load_config(), {"control.fade_time_s": 0.01})
    loop, ref = FeedbackLoop(cfg, 1), FeedbackLoop(cfg, 1, enabled=True)
    x = 1e-5 * np.random.default_rng(1).standard_normal((200, 1))
    for k in range(200):
        if k == 100:
            loop.enable(True)
        y, y_ref = loop.step(x[k]), ref.step(x[k])
        fade = min(max(k - 99, 0), 20) / 20
        assert_allclose(y, fade * y_ref, rtol=1e-12, atol=0)
    assert loop.enabled


def test_anti_windup_state_frozen_and_fast_recovery():
    """A saturating burst does not wind the filters up; the output recovers at once."""
    cfg = load_config()
    loop, ref = FeedbackLoop(cfg, 1, enabled=True), FeedbackLoop(cfg, 1, enabled=True)
    rng = np.random.default_rng(2)
    quiet = 1e-5 * rng.standard_normal((400, 1))
    for row in quiet[:200]:
        loop.step(row)
        ref.step(row)
    before = np.abs(loop._filter.get_state()).max()
    for k in range(1000):  # 10 m/s: thousands of newtons wanted, 400 N available
        w = loop.step([5.0 * math.sin(2 * math.pi * 3.0 * k / FS) + 10.0])
        assert abs(w[0]) <= loop.allocator.limit
        assert np.abs(loop._filter.get_state()).max() <= before + 1e-12
    assert loop.saturations == 1000
    after = [loop.step(row) for row in quiet[200:]]
    expected = [ref.step(row) for row in quiet[200:]]
    assert_allclose(after, expected, rtol=1e-12, atol=0)
    assert loop.last_saturated == 0


def test_saturating_sine_recovers_within_few_samples():
    """After a saturating sine stops, saturation ends within a few samples and states stay
    bounded."""
    cfg = load_config()
    loop = FeedbackLoop(cfg, 1, enabled=True)
    for k in range(4000):
        loop.step([0.05 * math.sin(2 * math.pi * 5.0 * k / FS)])
        assert np.abs(loop._filter.get_state()).max() < 1e4
    assert loop.saturations > 0
    n_sat = [0]
    for _ in range(20):
        loop.step([0.0])
        n_sat.append(loop.last_saturated)
    assert not any(n_sat[4:])


def test_clipped_output_is_wrench_of_clipped_forces():
    """When saturated, the output is the wrench of the clipped actuator forces (6dof)."""
    cfg = sixdof_config(**{"feedback.stage1.gain": [3e4] * 6})
    loop = FeedbackLoop(cfg, 1, enabled=True)
    w = loop.step(np.full(6, 1.0))
    assert loop.last_saturated > 0
    f = loop.allocator.forces(w)
    assert np.max(np.abs(f)) <= loop.allocator.limit * (1 + 1e-12)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_input_gives_zero_and_skips_update(bad):
    """NaN/Inf input gives zero output, is counted and leaves the states untouched."""
    cfg = load_config()
    loop, ref = FeedbackLoop(cfg, 1, enabled=True), FeedbackLoop(cfg, 1, enabled=True)
    x = 1e-5 * np.random.default_rng(4).standard_normal((60, 1))
    for k in range(60):
        if k == 30:
            assert_allclose(loop.step([bad]), [0.0])
        y = loop.step(x[k])
        assert np.isfinite(y).all()
        assert_allclose(y, ref.step(x[k]), rtol=0, atol=0)
    assert loop.nonfinite == 1


def test_zero_gain_axes_skipped():
    """Only axes with a non-zero gain get a filter; the others output zero."""
    loop = FeedbackLoop(sixdof_config(), 2, enabled=True)
    assert sorted(loop.tfs) == [2]
    y = loop.step(np.full(6, 1e-6))
    assert np.all(y[[0, 1, 3, 4, 5]] == 0.0) and y[2] != 0.0


@pytest.mark.parametrize(("cid", "kind", "stage"), [
    ("fb_stage1", FeedbackLoop, 1), ("fb_stage2", FeedbackLoop, 2),
    ("ff_stage1", FeedforwardLoop, 1),
])
def test_make_controller(cid, kind, stage):
    """Controller ids build the matching loop."""
    c = make_controller(load_config(), cid, enabled=True)
    assert isinstance(c, kind) and c.stage_index == stage and c.enabled


@pytest.mark.parametrize("cid", ["fb_stage3", "ff_stage2", "foo", "fb_stage0"])
def test_make_controller_rejects_unknown(cid):
    """Unknown ids and missing stages raise ConfigError."""
    with pytest.raises(ConfigError):
        make_controller(load_config(), cid)


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
@pytest.mark.parametrize("cid", ["fb_stage1", "ff_stage1"])
def test_a_copied_loop_continues_exactly_and_alone(how, cid):
    """A copy (the float step reads the filter state through views) steps on from the same
    state to the same bits, and stepping it leaves the original's state alone."""
    loop = make_controller(load_config(), cid, enabled=True)
    rng = np.random.default_rng(5)
    for v in rng.normal(scale=1e-3, size=50):
        loop.step([v])
    twin = copy.deepcopy(loop) if how == "deepcopy" else pickle.loads(pickle.dumps(loop))
    state = loop.filter.get_state()
    xs = rng.normal(scale=1e-3, size=40)
    got = [twin.step([v])[0] for v in xs]
    np.testing.assert_array_equal(loop.filter.get_state(), state)  # the original untouched
    assert got == [loop.step([v])[0] for v in xs]
