"""The margins' own root finder and minimiser against analytic solutions and scipy's."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import optimize

from dcsms_ros.core.solvers import RTOL, brent_root, nelder_mead


@pytest.mark.parametrize("fun, a, b, root", [
    (lambda x: math.cos(x) - x, 0.0, 1.0, 0.7390851332151607),
    (lambda x: x**3 - 2.0, 0.0, 2.0, 2.0 ** (1.0 / 3.0)),
    (lambda x: math.tanh(50.0 * (x - 0.3)), -1.0, 1.0, 0.3),  # a near step: bisection steps
    (lambda x: (x - 1e-3) * 1e6, -5.0, 5.0, 1e-3),  # linear: one secant step
    (lambda x: 1.0 - x, 1.0, 2.0, 1.0),  # a root on the bracket's end
])
@pytest.mark.parametrize("xtol", [1e-12, 1e-6])
def test_brent_root_finds_the_analytic_root_within_its_tolerance(fun, a, b, root,
                                                                 xtol) -> None:
    x = brent_root(fun, a, b, xtol=xtol)
    assert abs(x - root) <= xtol + 2 * RTOL * abs(root) + 1e-15


def test_brent_root_agrees_with_scipy_on_the_margins_crossings() -> None:
    """|L| - 1 of a second-order loop gain, the function the margins refine, between grid
    points (Hz) with the margins' tolerance: the same crossover as scipy's brentq."""
    def mag(f: float) -> float:
        s = 2j * math.pi * f
        return abs(4e4 / (s * (s + 30.0) * (s + 200.0)) * (s + 10.0)) - 1.0

    grid = np.geomspace(0.1, 100.0, 60)
    values = np.array([mag(f) for f in grid])
    k = int(np.nonzero(np.sign(values[:-1]) != np.sign(values[1:]))[0][0])
    ours = brent_root(mag, grid[k], grid[k + 1], xtol=1e-9 * grid[k])
    theirs = optimize.brentq(mag, grid[k], grid[k + 1], xtol=1e-9 * grid[k])
    assert_allclose(ours, theirs, rtol=2e-9)
    assert abs(mag(ours)) < 1e-7


def test_brent_root_refuses_an_unbracketed_interval() -> None:
    with pytest.raises(ValueError, match="no sign change"):
        brent_root(lambda x: x * x + 1.0, -1.0, 1.0, xtol=1e-9)


@pytest.mark.parametrize("x0", [[-1.2, 1.0], [0.0, 0.0], [2.0, 3.0]])
def test_nelder_mead_finds_the_rosenbrock_minimum_like_scipy(x0) -> None:
    def rosen(x: np.ndarray) -> float:
        return float(100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2)

    x, value = nelder_mead(rosen, x0, xatol=1e-8, fatol=1e-12, maxiter=2000)
    ref = optimize.minimize(rosen, x0, method="Nelder-Mead",
                            options={"xatol": 1e-8, "fatol": 1e-12, "maxiter": 2000})
    assert_allclose(x, [1.0, 1.0], atol=1e-6)
    assert_allclose(x, ref.x, atol=1e-6)
    assert value == pytest.approx(rosen(x)) and value < 1e-12


def test_nelder_mead_returns_the_best_vertex_when_iterations_run_out() -> None:
    """Few iterations: not converged, but the value is that of the point returned and no
    worse than the start."""
    def bowl(x: np.ndarray) -> float:
        return float(np.sum((x - np.array([3.0, -1.0, 0.5])) ** 2))

    x0 = np.zeros(3)
    x, value = nelder_mead(bowl, x0, xatol=1e-12, fatol=1e-12, maxiter=5)
    assert value == bowl(x) and value <= bowl(x0)
    x, value = nelder_mead(bowl, x0, xatol=1e-10, fatol=1e-14, maxiter=3000)
    assert_allclose(x, [3.0, -1.0, 0.5], atol=1e-8)


def test_the_stability_guard_does_not_import_scipy_optimize() -> None:
    """Every controller and mode_switch holds the guard: its imports stay without
    scipy.optimize (~0.35 s of CPU at each process start)."""
    code = ("import sys, dcsms_ros.ros.stability, dcsms_ros.nodes.feedback_controller, "
            "dcsms_ros.nodes.mode_switch; print('scipy.optimize' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("seed", range(6))
def test_nelder_mead_matches_scipy_on_the_d_scaling_of_the_disk_margin(seed: int) -> None:
    """The objective the disk margin minimises (sigma_max of D M D^-1 over log D, the
    margins' tolerances) on random complex 3 x 3 and 4 x 4 matrices: the same minimum as
    scipy's Nelder-Mead."""
    rng = np.random.default_rng(seed)
    n = 3 + seed % 2
    m = rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n))
    m[0, 1:] *= 20.0  # badly scaled, so the scaling matters

    def smax(x: np.ndarray) -> float:
        d = np.exp(np.concatenate([[0.0], x]))
        return float(np.linalg.norm((d[:, None] * m) / d[None, :], 2))

    top = float(np.linalg.norm(m, 2))
    opts = {"xatol": 1e-5, "fatol": 1e-7 * top, "maxiter": 200 * n}
    _, ours = nelder_mead(smax, np.zeros(n - 1), **opts)
    ref = optimize.minimize(smax, np.zeros(n - 1), method="Nelder-Mead", options=opts)
    assert ours < 0.5 * top  # the scaling did its work
    assert ours == pytest.approx(float(ref.fun), rel=1e-6)
