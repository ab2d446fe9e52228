"""CompiledPlant against PlantSimulator: the same readings, true twists, applied forces and
counters, sample for sample, across its draw blocks; the same errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from dcsms_ros.core import compiledplant, fastsim
from dcsms_ros.core.compiledplant import DRAW_BLOCK, CompiledPlant, plant_simulator
from dcsms_ros.core.config import load_config
from dcsms_ros.core.disturbance import BLOCK
from dcsms_ros.core.sensors import NOISE_BLOCK
from dcsms_ros.core.simulator import PlantSimulator

#: Samples that cross the draw blocks and the noise sources' own blocks twice.
SPAN = int(2.5 * max(DRAW_BLOCK, BLOCK, NOISE_BLOCK))

CONFIG = Path(__file__).resolve().parents[2] / "config"

pytestmark = pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")


def _run_both(a: PlantSimulator, b: PlantSimulator, samples: int, seed: int = 5,
              excite_every: int = 3, nan_every: int = 97, loud_every: int = 7,
              tuples: bool = False) -> None:
    """Step both with the same wrenches (some saturating, some non-finite, an excitation every
    ``excite_every`` samples) and compare everything a node reads of them; ``tuples``: ``b``
    gets them as tuples of Python floats, as the plant node reads them."""
    rng = np.random.default_rng(seed)
    n, dof = a.cfg.plant.num_stages, a.dof
    ids = [c for c in ("fb_stage1", "ff_stage1", "fb_stage2") if int(c[-1]) <= n]
    loud = 3.0 * max(al.limit for al in a.allocators) * np.sqrt(dof)
    for k in range(samples):
        assert_array_equal(a.truth(), b.truth(), err_msg=f"truth at {k}")
        assert_array_equal(a.measure(), b.measure(), err_msg=f"readings at {k}")
        for x, y in zip(a.sample_inputs, b.sample_inputs, strict=True):
            assert_array_equal(x, y)
        scale = loud if k % loud_every == 0 else 0.05
        w = {c: rng.normal(0.0, scale, dof) for c in ids}
        if k % nan_every == 0:
            w[ids[0]][0] = np.nan
        exc = (rng.normal(0.0, 0.01, (n, dof)) if k % excite_every == 0 else None)
        if exc is not None and k % (nan_every * excite_every) == 0:
            exc[0, 0] = np.inf
        wb = {c: tuple(v.tolist()) for c, v in w.items()} if tuples else w
        assert_array_equal(a.advance({c: v.copy() for c, v in w.items()}, exc),
                           b.advance(wb, exc), err_msg=f"applied at {k}")
        assert (a.k, a.saturations, a.nonfinite_inputs) == (b.k, b.saturations,
                                                             b.nonfinite_inputs)


@pytest.mark.parametrize("tuples", [False, True])
@pytest.mark.parametrize("name", ["table1.yaml", "tem_three_point.yaml", "tem_paper_fit.yaml"])
def test_the_compiled_plant_is_the_object_path_to_the_bit(name: str, tuples: bool) -> None:
    """Over 2.5 draw and noise blocks, with saturation, non-finite wrenches and excitation;
    the compiled plant's band-passes run compiled, the object's in Python; the compiled one's
    wrenches as arrays or as tuples of floats."""
    cfg = load_config(CONFIG / name)
    a, b = PlantSimulator(cfg, seed=11), CompiledPlant(cfg, seed=11)
    _run_both(a, b, SPAN, tuples=tuples)
    assert a.saturations > 0 and a.nonfinite_inputs > 0  # the test reached those paths


def test_a_replayed_ground_and_no_disturbances_are_the_object_paths() -> None:
    cfg = load_config(CONFIG / "table1.yaml")
    ground = np.random.default_rng(2).normal(0.0, 1e-6, (300, cfg.plant.dof))
    with pytest.warns(RuntimeWarning, match="ground replay ended"):
        _run_both(PlantSimulator(cfg, ground=ground), CompiledPlant(cfg, ground=ground), 700)
    _run_both(PlantSimulator(cfg, disturbances=False), CompiledPlant(cfg, disturbances=False),
              300)


def test_a_wrench_of_the_wrong_size_is_refused_as_the_object_path_refuses_it() -> None:
    cfg = load_config(CONFIG / "table1.yaml")
    msgs = []
    for sim in (PlantSimulator(cfg), CompiledPlant(cfg)):
        for w in (np.zeros(cfg.plant.dof + 1), (0.0,) * (cfg.plant.dof + 1)):
            with pytest.raises(ValueError) as err:
                sim.advance({"fb_stage1": w})
            msgs.append(str(err.value))
    assert len(set(msgs)) == 1 and "degrees of freedom" in msgs[0]


def test_building_it_leaves_the_state_at_rest() -> None:
    """The warm-up call (compiling the kernel) does not advance the plant or its filters."""
    cfg = load_config(CONFIG / "tem_three_point.yaml")
    sim = CompiledPlant(cfg)
    assert not sim.plant.x.any() and not sim.geophones.filter.arrays[5].any()
    assert (sim.k, sim.saturations, sim.nonfinite_inputs) == (0, 0, 0)


def test_plant_simulator_builds_the_object_one_without_numba(
        monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = load_config(CONFIG / "table1.yaml")
    assert type(plant_simulator(cfg)) is CompiledPlant
    monkeypatch.setattr(compiledplant, "available", lambda: False)
    assert type(plant_simulator(cfg)) is PlantSimulator
