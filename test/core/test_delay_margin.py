"""Delay margins: analytic loops, the loop as it runs with a whole-sample delay line, and the
batch engine with its forces held back (the analytic claim checked by simulation)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from dcsms_ros.core.check import check_mode
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.margins import OpenLoops, delay_margin, delay_margins, late_force_reason
from dcsms_ros.core.modes import Mode

ROOT = Path(__file__).resolve().parents[2]
F = np.geomspace(1e-3, 1e3, 4000)


def _integrator(k):
    return lambda f: k / (2j * np.pi * np.asarray(f, float))


@pytest.mark.parametrize("k", [0.5, 3.0, 40.0])
def test_integrator_loop_has_its_quarter_turn_over_crossover(k):
    """L = k/s crosses |L| = 1 at w = k with 90 deg of phase margin: tau = pi / (2 k)."""
    tau, f = delay_margin(_integrator(k), F)
    np.testing.assert_allclose([tau, f], [math.pi / (2 * k), k / (2 * math.pi)], rtol=1e-7)


@pytest.mark.parametrize("a", [0.3, 1.0, 4.0])
def test_double_integrator_with_lead(a):
    """L = (s + a) / s^2: phase -180 + atan(w/a) at the crossover w_c, so tau = atan(w_c/a)/w_c,
    where |L(w_c)| = 1 gives w_c^4 = w_c^2 + a^2."""
    def lfun(f):
        s = 2j * np.pi * np.asarray(f, float)
        return (s + a) / s**2

    wc = math.sqrt((1 + math.sqrt(1 + 4 * a * a)) / 2)
    tau, _ = delay_margin(lfun, F)
    assert tau == pytest.approx(math.atan(wc / a) / wc, rel=1e-7)


@pytest.mark.parametrize("theta", [0.0, 0.3, 1.0])
def test_coupled_loops_use_the_eigenvalue_that_lags(theta):
    """L = (k/s) R(theta) has eigenvalues (k/s) e^(+-j theta), both crossing at w = k: the one
    lagging by theta reaches -1 after (pi/2 - theta) / k."""
    k = 2.0
    rot = np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]])

    def lfun(f):
        return _integrator(k)(f)[:, None, None] * rot[None]

    tau, _ = delay_margin(lfun, F)
    assert tau == pytest.approx((math.pi / 2 - theta) / k, rel=1e-7)


def test_no_crossover_no_margin():
    tau, f = delay_margin(lambda x: 0.5 / (1 + 1j * np.asarray(x, float)), F)
    assert tau == math.inf and math.isnan(f)


def _spectral_radius(ol, paths, d):
    """Largest |pole| of the loop with ``d`` samples of delay on ``paths`` (indices of breaks),
    every other path closed: an exact discrete model built here, apart from the margin code."""
    m = ol.model
    assert float(np.abs(m.d).max()) == 0.0  # a force acts from the next sample
    n, jn = m.a.shape[0], len(paths)
    rest = [i for i in range(len(ol.breaks)) if i not in paths]
    a = np.zeros((n + d * jn, n + d * jn))
    a[:n, :n] = m.a + m.b[:, rest] @ m.c[rest]
    a[:n, n:n + jn] = m.b[:, paths]  # the oldest slot drives the plant
    for s in range(d - 1):
        a[n + s * jn:n + (s + 1) * jn, n + (s + 1) * jn:n + (s + 2) * jn] = np.eye(jn)
    a[n + (d - 1) * jn:, :n] = m.c[paths]
    return float(np.abs(np.linalg.eigvals(a)).max())


CASES = [("table1.yaml", Mode.FBC, "fb_stage1"), ("table1.yaml", Mode.DFBC, "fb_stage2"),
         ("table1.yaml", Mode.DFBC, "all"), ("tem_paper_fit.yaml", Mode.DFBC, "all")]


@pytest.mark.parametrize(("preset", "mode", "group"), CASES)
def test_margin_is_the_first_unstable_whole_sample_delay(preset, mode, group):
    """A delay of floor(tau fs) samples leaves the loop stable, one more sample makes it
    unstable: the margin is exact to the sample on the discrete loop."""
    cfg = load_config(ROOT / "config" / preset)
    ol = OpenLoops(cfg, mode)
    dm = {d.name: d for d in delay_margins(cfg, mode, loops_=ol)}[group]
    paths = [i for i, name in enumerate(ol.names) if name in dm.paths]
    d = math.floor(dm.delay_s * cfg.plant.rate_hz)
    assert _spectral_radius(ol, paths, d) < 1.0 < _spectral_radius(ol, paths, d + 1)


def _quarters(res):
    v = res.truth[:, 1:].reshape(len(res.t), -1)
    q = len(v) // 4
    return [float(np.sqrt(np.mean(v[i * q:(i + 1) * q] ** 2))) for i in range(4)]


@pytest.mark.parametrize(("preset", "mode", "group"),
                         [*CASES[:3], ("tem_paper_fit.yaml", Mode.DFBC, "fb_stage1")])
def test_engine_with_late_forces_agrees(preset, mode, group):
    """The batch engine with every force of ``group`` held back: 2 samples short of the
    margin the stages stay at their noise level; 3 samples beyond it they ring up (actuator
    saturation bounds them)."""
    cfg = load_config(ROOT / "config" / preset)
    dm = {d.name: d for d in delay_margins(cfg, mode)}[group]
    ids = [c for c in ("fb_stage1", "fb_stage2") if group in ("all", c)]
    d = math.floor(dm.delay_s * cfg.plant.rate_hz)
    short = _quarters(simulate(cfg, mode, 8.0, seed=3, trip=False,
                               delay=dict.fromkeys(ids, d - 2)))
    late = _quarters(simulate(cfg, mode, 8.0, seed=3, trip=False,
                              delay=dict.fromkeys(ids, d + 3)))
    assert short[3] < 2.0 * short[0]
    assert late[3] > 5.0 * short[3]


def test_check_fails_a_timeout_beyond_the_margin():
    """The TEM's stage-1 loops tolerate 10.7 ms: a 10 ms timeout passes, 11 ms fails and names
    the margin."""
    cfg = load_config(ROOT / "config" / "tem_paper_fit.yaml")
    assert check_mode(cfg, Mode.FBC).ok
    bad = check_mode(with_overrides(cfg, {"control.input_timeout_s": 0.011}), Mode.FBC)
    assert not bad.ok
    assert any("delay margin of fb_stage1" in f and "10.7 ms" in f for f in bad.failures)


@pytest.mark.parametrize("config, mode", [("table1.yaml", Mode.DFBC),
                                          ("tem_paper_fit.yaml", Mode.DFBC_FFC)])
def test_late_force_reason_refuses_exactly_beyond_the_smallest_margin(config, mode):
    """The real-time guard's verdict: forces 1 % less late than the smallest delay margin of
    one controller or all together (the margins the engine test above checks against the
    batch engine) pass; 1 % more late is refused, naming that margin."""
    cfg = load_config(ROOT / "config" / config)
    worst = min(delay_margins(cfg, mode), key=lambda d: d.delay_s)
    assert late_force_reason(cfg, mode) is None  # the presets' timeouts are inside
    assert late_force_reason(cfg, mode, 0.99 * worst.delay_s) is None
    reason = late_force_reason(cfg, mode, 1.01 * worst.delay_s)
    assert reason is not None and f"delay margin of {worst.name} is " in reason
    assert f"{worst.delay_s * 1e3:.1f} ms" in reason and mode.label in reason
    slow = with_overrides(cfg, {"control.input_timeout_s": round(1.01 * worst.delay_s, 4)})
    assert late_force_reason(slow, mode) is not None
    assert late_force_reason(cfg, Mode.FFC) is None  # no loop closed: nothing to be late for
