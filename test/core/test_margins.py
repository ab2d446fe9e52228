"""Margins of the loop as it runs: definitions checked against python-control, exact mu
values and the closed loop itself."""

from __future__ import annotations

from pathlib import Path

import control as ct
import numpy as np
import pytest

from dcsms_ros.core.check import stability
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.margins import (
    OpenLoops,
    _mu_upper,
    disk_from_alpha,
    disk_margin,
    frequency_grid,
    margins,
)
from dcsms_ros.core.modes import Mode

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def table1():
    return load_config(ROOT / "config" / "table1.yaml")


@pytest.mark.parametrize("k", [0.5, 2.0, 8.0])
def test_siso_disk_margin_equals_python_control(k):
    """For one loop the disk margin (alpha, gain, phase) is python-control's."""
    loop = ct.tf([k], [1.0, 1.2, 1.0]) * ct.tf([1.0], [0.05, 1.0])
    w = np.geomspace(1e-2, 1e2, 3000)
    dm, dgm, dpm = ct.disk_margins(loop, w)
    h = np.asarray(loop(1j * w), dtype=complex)
    alpha, _ = disk_margin(h, w / (2 * np.pi))
    gm, pm = disk_from_alpha(alpha)
    assert alpha == pytest.approx(float(dm), rel=1e-9)
    assert gm == pytest.approx(float(dgm), rel=1e-6)
    assert pm == pytest.approx(float(dpm), rel=1e-6)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_mu_upper_bound_is_exact_for_rank_one(seed):
    """mu of u v^H over independent complex scalars is sum |u_i v_i| (exact); the D-scaled
    bound reaches it (it is exact for up to three blocks)."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(3) + 1j * rng.standard_normal(3)
    v = rng.standard_normal(3) + 1j * rng.standard_normal(3)
    m = np.outer(u, v.conj())
    assert _mu_upper(m) == pytest.approx(float(np.sum(np.abs(u) * np.abs(v))), rel=1e-4)
    assert _mu_upper(np.diag(u)) == pytest.approx(float(np.max(np.abs(u))), rel=1e-6)


def _scaled_gain(cfg, stage: int, factor: float):
    name = f"feedback.stage{stage}.gain"
    return with_overrides(cfg, {name: [factor * g for g in cfg.params[name]]})


def test_gain_margin_is_where_the_closed_loop_goes_unstable(table1):
    """fb_stage2's loop-at-a-time gain margin in DFBC: the loop as it runs stays stable 0.3 dB
    inside it and is unstable 0.3 dB beyond it."""
    loops, _ = margins(table1, Mode.DFBC)
    m = next(x for x in loops if x.controller == "fb_stage2")
    assert 6.0 < m.gm_db < 40.0
    inside = _scaled_gain(table1, 2, 10 ** ((m.gm_db - 0.3) / 20))
    beyond = _scaled_gain(table1, 2, 10 ** ((m.gm_db + 0.3) / 20))
    assert stability(inside, Mode.DFBC).stable
    worst = stability(beyond, Mode.DFBC)
    assert not worst.stable
    assert abs(worst.worst_s_hz.imag) == pytest.approx(m.wp_hz, rel=0.05)


def test_phase_margin_reads_the_loop_at_its_gain_crossover(table1):
    """At the reported gain crossover |L| = 1 and the angle is the phase margin from -180."""
    ol = OpenLoops(table1, Mode.DFBC)
    loops, _ = margins(table1, Mode.DFBC)
    for i, m in enumerate(loops):
        if not np.isfinite(m.pm_deg):
            continue
        v = complex(ol.siso(i)(np.array([m.wg_hz]))[0])
        assert abs(v) == pytest.approx(1.0, abs=1e-6)
        assert 180.0 - abs(np.degrees(np.angle(v))) == pytest.approx(m.pm_deg, abs=1e-6)


def test_disk_margin_of_a_stage_bounds_every_one_of_its_paths():
    """Opening all of a stage's paths together cannot tolerate more than any one path alone
    (same frequency grid): the multiloop disk is at most each loop's own disk."""
    cfg = load_config(ROOT / "config" / "tem_three_point.yaml")
    ol = OpenLoops(cfg, Mode.DFBC)
    f = frequency_grid(cfg.plant.rate_hz, 600)
    g = ol.g(f)
    for idx in ol.stage_paths().values():
        multi, _ = disk_margin(ol.loop_gain(g, idx), f)
        for i in idx:
            single, _ = disk_margin(ol.loop_gain(g, [i]), f)
            assert multi <= single * (1 + 1e-9)
