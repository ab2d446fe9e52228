"""CompiledDecoupler against Decoupler: the same twists and counter, sample for sample, with
non-finite readings (the object's path) between compiled samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from dcsms_ros.core import compileddecoupler, fastsim
from dcsms_ros.core.compileddecoupler import CompiledDecoupler, decoupler
from dcsms_ros.core.config import load_config
from dcsms_ros.core.decoupling import Decoupler

CONFIG = Path(__file__).resolve().parents[2] / "config"

pytestmark = pytest.mark.skipif(not fastsim.available(), reason="numba is not installed")


@pytest.mark.parametrize("name", ["table1.yaml", "tem_three_point.yaml", "tem_paper_fit.yaml"])
def test_the_compiled_decoupler_is_the_object_path_to_the_bit(name: str) -> None:
    cfg = load_config(CONFIG / name)
    a, b = Decoupler(cfg), CompiledDecoupler(cfg)
    rng = np.random.default_rng(4)
    outs = []
    for k in range(3000):
        raw = rng.normal(0.0, 1e-5, a.n_channels) + 1e-4 * np.sin(k / 50.0)
        if k % 101 == 0:
            raw[k % a.n_channels] = np.nan if k % 2 else np.inf
        want, got = a.step(raw.copy()), b.step(raw)
        assert_array_equal(want, got, err_msg=f"sample {k}")
        outs.append(got)
    assert a.nonfinite == b.nonfinite > 0
    assert not np.shares_memory(outs[-1], outs[-2])  # a new array each sample, as the object's
    assert_array_equal(a.extension.arrays[5], b.extension.arrays[5])


def test_building_it_leaves_the_filters_at_rest() -> None:
    b = CompiledDecoupler(load_config(CONFIG / "tem_three_point.yaml"))
    assert not b.extension.arrays[5].any()


def test_decoupler_builds_the_object_one_without_numba(monkeypatch: pytest.MonkeyPatch) -> None:
    cfg = load_config(CONFIG / "table1.yaml")
    assert type(decoupler(cfg)) is CompiledDecoupler
    monkeypatch.setattr(compileddecoupler, "available", lambda: False)
    assert type(decoupler(cfg)) is Decoupler
