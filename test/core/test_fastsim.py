"""The array API the fast engine reads: shared arrays, the documented recursion, the kernel."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from dcsms_ros.core import fastsim
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.controllers import Fader, FeedbackLoop
from dcsms_ros.core.decoupling import Decoupler
from dcsms_ros.core.engine import Simulation
from dcsms_ros.core.filters import feedback_sos
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.simulator import PlantSimulator
from dcsms_ros.core.sosfilter import SosFilter


def _sos_by_the_docstring(arrays: tuple[np.ndarray, ...], u: np.ndarray) -> np.ndarray:
    """SosArrays' documented recursion written out independently of SosFilter.step."""
    b0, b1, b2, a1, a2, z = arrays
    y = u.copy()
    for i in range(b0.shape[0]):
        for c in range(y.shape[0]):
            x = y[c]
            out = b0[i, c] * x + z[i, 0, c]
            z[i, 0, c] = b1[i, c] * x - a1[i, c] * out + z[i, 1, c]
            z[i, 1, c] = b2[i, c] * x - a2[i, c] * out
            y[c] = out
    return y


def _filter(cfg: SystemConfig) -> SosFilter:
    fb = cfg.feedback[0]
    return SosFilter(np.stack([feedback_sos(fb, 2, cfg.plant.rate_hz)] * 3), 3)


def test_sos_arrays_are_the_filters_own(cfg: SystemConfig) -> None:
    f = _filter(cfg)
    a = f.arrays
    f.step(np.array([1.0, -2.0, 0.5]))
    assert_array_equal(a.state, f.get_state())
    assert np.any(a.state != 0.0)
    a.state[...] = 0.0  # writing the shared state resets the filter
    assert_array_equal(f.get_state(), 0.0)
    coef = f.coefficients()
    for j, arr in zip((0, 1, 2, 4, 5), a[:5], strict=True):
        assert_array_equal(arr, coef[:, :, j].T)


def test_documented_recursion_on_the_arrays_is_step_bit_for_bit(cfg: SystemConfig) -> None:
    f, g = _filter(cfg), _filter(cfg)
    u = np.random.default_rng(3).standard_normal((200, 3))
    for row in u:
        assert_array_equal(_sos_by_the_docstring(tuple(g.arrays), row), f.step(row))
    assert_array_equal(f.get_state(), g.get_state())


@pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")
def test_compiled_section_kernel_on_the_arrays_is_step_bit_for_bit(cfg: SystemConfig) -> None:
    from dcsms_ros.core import fastloop  # numba is optional: imported only when present

    f, g = _filter(cfg), _filter(cfg)
    for row in np.random.default_rng(4).standard_normal((200, 3)):
        y = row.copy()
        fastloop._sos(*g.arrays, y)
        assert_array_equal(y, f.step(row))


def test_fader_count_and_steps_give_its_value() -> None:
    f = Fader(0.01, 0.001)
    assert (f.steps, f.count, f.target) == (10, 0, False)
    f.set_target(True)
    for _ in range(4):
        f.step()
    assert f.count == 4
    assert f.value == f.count / f.steps


def test_plant_and_loop_arrays_are_what_they_step_with(cfg: SystemConfig) -> None:
    sim = PlantSimulator(cfg)
    p = sim.plant
    x0 = np.random.default_rng(5).standard_normal(p.a.shape[0])
    p.x[:] = x0
    u = np.random.default_rng(6).standard_normal(p.n_inputs)
    p.step(u)
    assert_array_equal(p.x, np.dot(p.a, x0) + np.dot(p.b, u))
    assert_array_equal(p.output(), np.dot(p.c, p.x))
    ground, table = sim.sample_inputs
    assert ground.shape == (cfg.plant.dof,)
    assert table.shape == (cfg.plant.num_stages, cfg.plant.dof)

    loop = FeedbackLoop(cfg, 1, enabled=True)
    loop.step(np.full(cfg.plant.dof, 1e-6))
    before = loop.filter.get_state()
    loop.step(np.full(cfg.plant.dof, 2e-6))
    assert_array_equal(loop.saved_state, before)  # the state a saturated sample restores

    dec = Decoupler(cfg)
    assert dec.extension.channels == dec.n_channels
    assert sum(sl.stop - sl.start for sl, _ in dec.blocks) == dec.n_channels


@pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")
def test_fast_loop_advances_the_objects_own_states(cfg: SystemConfig) -> None:
    """After a fast run the objects hold the fast path's final state (no private copies)."""
    run = Simulation(cfg, Mode.DFBC_FFC, fast=True)
    run.run(500)
    assert run.sim.k == 500
    assert np.any(run.sim.plant.x != 0.0)
    assert np.any(run.dec.extension.get_state() != 0.0)
    assert all(np.any(c.filter.get_state() != 0.0) for c in run.ctrls.values())
