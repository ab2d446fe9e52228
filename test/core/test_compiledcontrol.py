"""The compiled controllers against the objects: the same wrenches, counters and filter states,
sample for sample, through fades, non-finite twists, saturation, priming, retuning and a pickled
copy (the object's own code between compiled samples)."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from dcsms_ros.core import compiledcontrol, fastsim
from dcsms_ros.core.compiledcontrol import (
    CompiledFeedbackLoop,
    CompiledFeedforwardLoop,
    controller,
)
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.controllers import FeedbackLoop, FeedforwardLoop, make_controller, retuned

CONFIG = Path(__file__).resolve().parents[2] / "config"
IDS = ["fb_stage1", "fb_stage2", "ff_stage1"]

pytestmark = pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")


def _same(a: FeedbackLoop | FeedforwardLoop, b: FeedbackLoop | FeedforwardLoop,
          where: str) -> None:
    assert (a.saturations, a.nonfinite, a.last_saturated) == \
        (b.saturations, b.nonfinite, b.last_saturated), where
    assert_array_equal(a.filter.get_state(), b.filter.get_state(), err_msg=where)
    assert_array_equal(a.saved_state, b.saved_state, err_msg=where)
    assert a.fader.count == b.fader.count, where


def _twists(dof: int, n: int, seed: int) -> np.ndarray:
    """Twists (n, dof) m/s whose amplitude sweeps 1e-7 .. 1e2 m/s (the top saturates every
    actuator), with NaN and inf here and there."""
    rng = np.random.default_rng(seed)
    amp = np.logspace(-7, 2, n)[:, None]
    x = amp * (rng.normal(size=(n, dof)) + np.sin(np.arange(n) / 40.0)[:, None])
    x[97::211, 0] = np.nan
    x[151::307, -1] = np.inf
    return x


@pytest.mark.parametrize("name", ["table1.yaml", "tem_three_point.yaml", "tem_paper_fit.yaml"])
@pytest.mark.parametrize("cid", IDS)
def test_the_compiled_step_is_the_object_path_to_the_bit(name: str, cid: str) -> None:
    cfg = load_config(CONFIG / name)
    a, b = make_controller(cfg, cid, enabled=False), controller(cfg, cid, enabled=False)
    assert isinstance(b, (CompiledFeedbackLoop, CompiledFeedforwardLoop))
    x = _twists(cfg.plant.dof, 4000, 7)
    outs = []
    for k, twist in enumerate(x):
        if k in (0, 1900):  # fade in, later out and in again
            a.enable(True), b.enable(True)
        if k == 1500:
            a.enable(False), b.enable(False)
        if k == 700:  # a controller joining a running plant
            a.prime(x[k - 1]), b.prime(x[k - 1])
        want, got = a.step(twist.copy()), b.step(twist)
        assert_array_equal(want, got, err_msg=f"sample {k}")
        _same(a, b, f"sample {k}")
        outs.append(got)
    assert a.nonfinite == b.nonfinite > 0
    assert a.saturations == b.saturations > 0
    assert not np.shares_memory(outs[-1], outs[-2])  # a new array each sample, as the object's


@pytest.mark.parametrize("cid", IDS)
def test_a_retuned_and_a_pickled_compiled_loop_go_on_as_the_objects(cid: str) -> None:
    cfg = load_config(CONFIG / "tem_three_point.yaml")
    a, b = make_controller(cfg, cid, enabled=True), controller(cfg, cid, enabled=True)
    x = _twists(cfg.plant.dof, 600, 3) * 1e-4
    for twist in x[:200]:
        a.step(twist), b.step(twist)
    tuned = with_overrides(cfg, {"control.fade_time_s": cfg.control.fade_time_s})
    a, b = retuned(a, tuned, cid), retuned(b, tuned, cid)
    assert type(b) is type(controller(cfg, cid))  # retuning keeps the compiled class
    for twist in x[200:400]:
        assert_array_equal(a.step(twist), b.step(twist))
    c = pickle.loads(pickle.dumps(b))  # its own arrays: the kernel's are rebuilt
    for twist in x[400:]:
        want = a.step(twist)
        assert_array_equal(want, c.step(twist))
        _same(a, c, "pickled copy")
    assert not np.shares_memory(c.filter.arrays.state, b.filter.arrays.state)


def test_a_twist_of_another_shape_is_the_object_paths() -> None:
    cfg = load_config(CONFIG / "table1.yaml")
    a, b = make_controller(cfg, "fb_stage1", True), controller(cfg, "fb_stage1", True)
    for twist in (np.array([1e-6, 2e-6]), np.ones((3, 2))[:, 0]):
        want = a.step(twist)
        assert_array_equal(want, b.step(twist))
        _same(a, b, str(twist.shape))
        floats = tuple(twist.tolist())  # a node's floats of another count
        assert b.step_floats(floats) == a.step_floats(floats)
        _same(a, b, f"floats {len(floats)}")
    with pytest.raises(TypeError) as want_err:
        a.step(np.array([[1e-6]]))
    with pytest.raises(TypeError) as got_err:
        b.step(np.array([[1e-6]]))
    assert str(got_err.value) == str(want_err.value)
    _same(a, b, "refused")


def test_building_one_leaves_its_states_as_they_were() -> None:
    cfg = load_config(CONFIG / "tem_three_point.yaml")
    b = controller(cfg, "fb_stage2", enabled=True)
    assert not b.filter.get_state().any() and not b.saved_state.any()
    b.step(np.full(cfg.plant.dof, 1e-5))
    state, saved = b.filter.get_state(), b.saved_state.copy()
    c = pickle.loads(pickle.dumps(b))  # unpickling compiles (loads) again on its own arrays
    assert_array_equal(c.filter.get_state(), state)
    assert_array_equal(c.saved_state, saved)


def test_controller_builds_the_objects_without_numba_or_when_asked(
        monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = load_config(CONFIG / "table1.yaml")
    assert type(controller(cfg, "ff_stage1")) is CompiledFeedforwardLoop
    assert type(controller(cfg, "fb_stage1", compiled=False)) is FeedbackLoop
    monkeypatch.setattr(compiledcontrol, "available", lambda: False)
    assert type(controller(cfg, "ff_stage1")) is FeedforwardLoop
    assert type(controller(cfg, "fb_stage2")) is FeedbackLoop


@pytest.mark.parametrize("name", ["table1.yaml", "tem_three_point.yaml"])
@pytest.mark.parametrize("cid", IDS)
def test_step_floats_is_step_to_the_bit_object_and_compiled(name: str, cid: str) -> None:
    """A node's floats path (tuples in, lists of Python floats out) answers as the arrays'
    path, through a sweep that saturates and feeds NaN and inf, with fades and a prime."""
    cfg = load_config(CONFIG / name)
    ref = make_controller(cfg, cid, enabled=False)
    loops = [make_controller(cfg, cid, enabled=False), controller(cfg, cid, enabled=False)]
    x = _twists(cfg.plant.dof, 3000, 11)
    for k, twist in enumerate(x):
        for c in (ref, *loops):
            if k in (0, 1900):
                c.enable(True)
            if k == 1500:
                c.enable(False)
            if k == 700:
                c.prime(tuple(x[k - 1].tolist()))
        want = ref.step(twist)
        for c in loops:
            got = c.step_floats(tuple(twist.tolist()))
            assert type(got) is list and all(type(v) is float for v in got)
            assert_array_equal(np.array(got), want, err_msg=f"sample {k}")
            _same(ref, c, f"sample {k}")
    assert ref.nonfinite > 0 and ref.saturations > 0
