"""Continuous cascade plant (1dof / 6dof), exact ZOH discretisation and the stepping plant."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from symmetric_helper import M1, M2, C, K, symmetric_6dof_flat

from dcsms_ros.core.config import config_from_flat, load_config
from dcsms_ros.core.model import (
    DiscretePlant,
    discretize,
    input_slices,
    mass_matrix,
    plant_state_space,
    reference_transform,
)
from dcsms_ros.errors import ConfigError

CONFIG = Path(__file__).resolve().parents[2] / "config"


@pytest.fixture(scope="module")
def table1():
    return load_config(CONFIG / "table1.yaml")


def _fr(ss, inp: int, out: int, f_hz: np.ndarray) -> np.ndarray:
    eye = np.eye(ss.a.shape[0])
    return np.array([ss.c[out] @ np.linalg.solve(2j * math.pi * f * eye - ss.a, ss.b[:, inp])
                     for f in f_hz])


def test_1dof_shapes_and_names(table1):
    """1dof, two stages: 4 states, inputs ground | 2 lumped actuators | 2 disturbances."""
    ss = plant_state_space(table1)
    assert ss.a.shape == (4, 4) and ss.b.shape == (4, 5) and ss.c.shape == (2, 4)
    assert ss.input_names == ("ground.vz", "stage1.act0", "stage2.act0", "stage1.wz",
                              "stage2.wz")
    assert ss.output_names == ("stage1.vz", "stage2.vz")
    np.testing.assert_array_equal(ss.d, 0.0)


def test_1dof_matrices_are_the_equations_of_motion(table1):
    """Velocity rows of A are the NOTES equations: m1 a1 = -k1 e1 - c1 de1 + k2 e2 + c2 de2."""
    a = plant_state_space(table1).a
    expected = np.array([
        [0, 0, 1, 0],
        [0, 0, -1, 1],
        [-K / M1, K / M1, -2 * C / M1, C / M1],
        [0, -K / M2, C / M2, -C / M2]])
    np.testing.assert_allclose(a, expected, rtol=1e-12)


def test_passive_plant_is_asymptotically_stable(table1):
    """Relative-displacement states leave no free integrator: every eigenvalue has Re < 0."""
    assert np.all(np.linalg.eigvals(plant_state_space(table1).a).real < 0)


@pytest.mark.parametrize("flat_fn", [lambda: {"plant.num_stages": 2},
                                     lambda: symmetric_6dof_flat((0.1, -0.05))])
def test_actuator_reaction_leaves_lower_stage_static(flat_fn):
    """A constant stage-2 actuator force deflects only spring 2 (reaction on stage 1)."""
    cfg = config_from_flat(flat_fn(), "<test>")
    ss = plant_state_space(cfg)
    _, act, _ = input_slices(cfg)
    dof = cfg.plant.dof
    n1 = 1 if dof == 1 else len(cfg.plant.stages[0].actuators.position)
    x_ss = -np.linalg.solve(ss.a, ss.b[:, act][:, n1])  # first stage-2 actuator, 1 N
    np.testing.assert_allclose(x_ss[:dof], 0.0, atol=1e-15)
    assert np.max(np.abs(x_ss[dof:2 * dof])) > 1e-8
    np.testing.assert_allclose(x_ss[2 * dof:], 0.0, atol=1e-15)


def test_force_at_com_gives_no_rotation():
    """Mass matrix with a CoM offset: a force through the CoM accelerates the CoM by f/m only."""
    cfg = config_from_flat(symmetric_6dof_flat((0.2, -0.1)), "<test>")
    for i, st in enumerate(cfg.plant.stages, 1):
        x = reference_transform(cfg, i)
        wrench = np.array([3.0, -2.0, 5.0, 0.0, 0.0, 0.0])
        qdd = np.linalg.solve(mass_matrix(cfg, i), x.T @ wrench)
        np.testing.assert_allclose(x @ qdd, np.r_[wrench[:3] / st.mass, 0, 0, 0], atol=1e-14)


def test_6dof_symmetric_z_equals_1dof(table1):
    """Four symmetric mounts: ground z -> stage z equals the 1dof model with summed k and c."""
    six = plant_state_space(config_from_flat(symmetric_6dof_flat(), "<test>"))
    one = plant_state_space(table1)
    f = np.geomspace(0.1, 1000.0, 200)
    for i in range(2):
        np.testing.assert_allclose(_fr(six, 2, 6 * i + 2, f), _fr(one, 0, i, f), rtol=1e-9)


def test_6dof_symmetric_eigenvalues_contain_1dof(table1):
    """The z-subsystem eigenvalues of the symmetric 6dof model are the 1dof eigenvalues."""
    six = np.linalg.eigvals(plant_state_space(config_from_flat(symmetric_6dof_flat(),
                                                               "<test>")).a)
    for lam in np.linalg.eigvals(plant_state_space(table1).a):
        assert np.min(np.abs(six - lam)) < 1e-9 * abs(lam)


def test_singular_mounts_fail_naming_field_and_file():
    """Mounts with vertical stiffness only cannot hold x, y, rz: ConfigError names them."""
    flat = symmetric_6dof_flat()
    flat["stage2.mounts.stiffness"] = [0.0, 0.0, K / 4] * 4
    with pytest.raises(ConfigError, match=r"rig\.yaml: stage2\.mounts"):
        config_from_flat(flat, "rig.yaml")


@pytest.mark.parametrize("inp,out", [(0, 1), (1, 0), (2, 1), (4, 1)])
def test_zoh_matches_continuous_within_0p1_db(table1, inp, out):
    """Exact ZOH at 2 kHz: |H(e^jwT)| within 0.1 dB of |H(jw)| over 1-100 Hz."""
    ss = plant_state_space(table1)
    dt = table1.plant.dt
    sd = discretize(ss, dt)
    f = np.geomspace(1.0, 100.0, 60)
    z = np.exp(2j * math.pi * f * dt)
    eye = np.eye(sd.a.shape[0])
    hd = np.array([sd.c[out] @ np.linalg.solve(zk * eye - sd.a, sd.b[:, inp]) for zk in z])
    err_db = 20 * np.log10(np.abs(hd) / np.abs(_fr(ss, inp, out, f)))
    assert np.max(np.abs(err_db)) < 0.1


def test_discretize_matches_scipy_cont2discrete(table1):
    """The augmented-exponential ZOH equals scipy's ZOH discretisation."""
    ss = plant_state_space(table1)
    ad, bd, *_ = signal.cont2discrete((ss.a, ss.b, ss.c, ss.d), 5e-4, method="zoh")
    sd = discretize(ss, 5e-4)
    np.testing.assert_allclose(sd.a, ad, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(sd.b, bd, rtol=1e-10, atol=1e-18)
    assert sd.dt == 5e-4


def test_discrete_plant_step_reproduces_dlsim():
    """DiscretePlant (y_k = C x_k, x_k+1 = Ad x_k + Bd u_k) equals scipy.signal.dlsim."""
    cfg = config_from_flat(symmetric_6dof_flat((0.1, 0.05)), "<test>")
    sd = discretize(plant_state_space(cfg), cfg.plant.dt)
    rng = np.random.default_rng(3)
    u = rng.standard_normal((400, sd.b.shape[1]))
    _, y_ref, _ = signal.dlsim((sd.a, sd.b, sd.c, sd.d, sd.dt), u)
    plant = DiscretePlant(sd)
    y = np.empty_like(y_ref)
    for k in range(u.shape[0]):
        y[k] = plant.output()
        plant.step(u[k])
    np.testing.assert_allclose(y, y_ref, rtol=1e-9, atol=1e-12 * np.max(np.abs(y_ref)))
    plant.reset()
    np.testing.assert_array_equal(plant.output(), 0.0)
