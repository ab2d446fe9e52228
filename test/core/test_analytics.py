"""Analytic transfer functions, modes, Routh-Hurwitz and loop margins against NOTES.md."""

from __future__ import annotations

import math
from pathlib import Path

import control as ct
import numpy as np
import pytest
from symmetric_helper import symmetric_6dof_flat

from dcsms_ros.core import analytics as an
from dcsms_ros.core.config import config_from_flat, load_config, scaled, with_overrides
from dcsms_ros.core.filters import feedback_tf, feedforward_tf
from dcsms_ros.core.model import plant_state_space
from dcsms_ros.core.modes import ALL_MODES, Mode

CONFIG = Path(__file__).resolve().parents[2] / "config"
TABLE1 = (988.8, 748.8, 1960.0, 1960.0, 1.2e6, 1.2e6)  # m1 m2 c1 c2 k1 k2
F = np.geomspace(0.1, 1000.0, 300)


@pytest.fixture(scope="module")
def table1():
    return load_config(CONFIG / "table1.yaml")


def test_eq9_eigenvalues_in_hz(table1):
    """Table 1 eigenvalues / 2pi as the paper prints them: -0.0729+-3.7677i, -0.4509+-9.3633i."""
    lam = [m.eigenvalue_hz for m in an.modes(table1)]
    got = [(round(z.real, 4), round(z.imag, 4)) for z in lam]
    assert got == [(-0.0729, 3.7677), (-0.4509, 9.3633)]
    roots = np.roots(an.characteristic_polynomial(table1)) / (2 * math.pi)
    np.testing.assert_allclose(np.sort_complex(roots[roots.imag > 0]),
                               [-0.4509 + 9.3633j, -0.0729 + 3.7677j], atol=6e-5)


def test_modes_match_exact_two_dof_figures(table1):
    """Natural frequencies and damping ratios: 3.7684 Hz / 1.934e-2, 9.3741 Hz / 4.810e-2."""
    m = an.modes(table1)
    np.testing.assert_allclose([x.frequency_hz for x in m], [3.7684, 9.3741], rtol=2e-5)
    np.testing.assert_allclose([x.damping_ratio for x in m], [1.934e-2, 4.810e-2], rtol=1e-3)


def test_characteristic_polynomial_is_the_notes_formula(table1):
    """det(M s^2 + C s + K) for N = 2 has NOTES.md's coefficients."""
    m1, m2, c1, c2, k1, k2 = TABLE1
    expected = [m1 * m2, c1 * m2 + c2 * m2 + c2 * m1, m2 * k1 + m2 * k2 + c1 * c2 + k2 * m1,
                c2 * k1 + k2 * c1, k1 * k2]
    np.testing.assert_allclose(an.characteristic_polynomial(table1), expected, rtol=1e-14)


def test_three_stage_polynomial_roots_are_state_space_eigenvalues():
    """N = 3: the continuant recurrence and the state-space A give the same eigenvalues."""
    cfg = config_from_flat({"plant.num_stages": 3, "stage3.mass": 300.0,
                            "stage3.stiffness": 4e5}, "<test>")
    roots = np.sort_complex(np.roots(an.characteristic_polynomial(cfg)))
    eig = np.sort_complex(np.linalg.eigvals(plant_state_space(cfg).a))
    np.testing.assert_allclose(roots, eig, rtol=1e-9)
    assert len(an.modes(cfg)) == 3


def test_stage_locked_frequency_is_4p18_hz(table1):
    """sqrt(k1 / (m1 + m2)) / 2pi = 4.18 Hz for Table 1."""
    np.testing.assert_allclose(an.stage_locked_frequency(table1), 4.18, atol=5e-3)
    np.testing.assert_allclose(an.uncoupled_frequencies(table1), [5.544, 6.37], atol=5e-3)


@pytest.mark.parametrize("param,factor", [("c2", 1e4), ("k2", 1e5)])
def test_locked_second_stage_limit(table1, param, factor):
    """With c2 or k2 huge the lowest mode tends to the stage-locked 4.18 Hz."""
    cfg = scaled(table1, param, factor)
    np.testing.assert_allclose(an.modes(cfg)[0].frequency_hz, an.stage_locked_frequency(table1),
                               rtol=2e-3)


def test_eq10_with_zero_controllers_is_eq4():
    """Eq. 10 with every H = 0 equals Eq. 4 over 0.1-1000 Hz."""
    np.testing.assert_allclose(an.freq_response(an.eq10_tf(*TABLE1), F),
                               an.freq_response(an.eq4_tf(*TABLE1), F), rtol=1e-12)


def test_ideal_feedforward_cancels_ground_path():
    """H1ffc = Z1 = c1 + k1/s makes v_p2/v_b vanish (NOTES: ideal feedforward)."""
    c1, k1 = TABLE1[2], TABLE1[4]
    tf = an.eq10_tf(*TABLE1, h1ffc=ct.tf([c1, k1], [1.0, 0.0]))
    assert np.max(np.abs(an.freq_response(tf, F))) < 1e-9


def test_transmissibility_passive_is_eq4(table1):
    """State-space passive v_p2/v_b equals Eq. 4; v_p1/v_b equals the Eq. 10 companion."""
    tr = an.transmissibility(table1, Mode.PASSIVE)
    np.testing.assert_allclose(an.freq_response(tr[1], F),
                               an.freq_response(an.eq4_tf(*TABLE1), F), rtol=1e-9)
    np.testing.assert_allclose(an.freq_response(tr[0], F),
                               an.freq_response(an.eq10_stage1_tf(*TABLE1), F), rtol=1e-9)


@pytest.mark.parametrize("mode", ALL_MODES, ids=lambda m: m.value)
def test_transmissibility_equals_eq10_with_filters(table1, mode):
    """Closed-loop state space equals Eq. 10 with the filters' H for every mode, both stages."""
    c = mode.controllers
    h = {"h1fbc": feedback_tf(table1.feedback[0], 2) if "fb_stage1" in c else 0.0,
         "h2fbc": feedback_tf(table1.feedback[1], 2) if "fb_stage2" in c else 0.0,
         "h1ffc": (feedforward_tf(table1.feedforward, TABLE1[2], TABLE1[4])
                   if "ff_stage1" in c else 0.0)}
    tr = an.transmissibility(table1, mode)
    np.testing.assert_allclose(an.freq_response(tr[1], F),
                               an.freq_response(an.eq10_tf(*TABLE1, **h), F), rtol=1e-7)
    np.testing.assert_allclose(an.freq_response(tr[0], F),
                               an.freq_response(an.eq10_stage1_tf(*TABLE1, **h), F), rtol=1e-7)


def test_ideal_sensors_leave_transmissibility_unchanged(table1):
    """sensors=True with ideal geophones (dynamics off) is the sensor-free closed loop."""
    ideal = with_overrides(table1, {"sensors.dynamics": False})
    a = an.transmissibility(ideal, Mode.DFBC_FFC, sensors=True)[1]
    b = an.transmissibility(table1, Mode.DFBC_FFC)[1]
    np.testing.assert_allclose(an.freq_response(a, F), an.freq_response(b, F), rtol=1e-7)


def test_dfbc_ffc_attenuates_the_resonance(table1):
    """At the 3.77 Hz resonance DFBC+FFC transmits far less than Passive (paper Table 4)."""
    f = np.array([3.768])
    passive = abs(an.freq_response(an.transmissibility(table1, Mode.PASSIVE)[1], f)[0])
    active = abs(an.freq_response(an.transmissibility(table1, Mode.DFBC_FFC)[1], f)[0])
    assert active / passive < 0.2


@pytest.mark.parametrize("coeffs,changes,stable", [
    ([1, 6, 11, 6], 0, True),                 # (s+1)(s+2)(s+3)
    ([1, 1, 2, 8], 2, False),                 # one real LHP root, an RHP pair
    ([1, 2, 2, 4, 11, 10], 2, False),         # Nise: zero row-free, two RHP roots
    ([1, 1, 2, 2, 3], 2, False),              # zero first element: epsilon rule
    ([1, 2, 1, 2], 0, False),                 # row of zeros: roots +-j
    ([1, -3, 2], 2, False),                   # (s-1)(s-2)
])
def test_routh_known_polynomials(coeffs, changes, stable):
    """Sign changes equal the number of RHP roots; imaginary-axis roots are not stable."""
    r = an.routh(coeffs)
    assert (r.sign_changes, r.stable) == (changes, stable)
    assert r.sign_changes == int(np.sum(np.roots(coeffs).real > 1e-9))
    assert r.array.shape == (len(coeffs), (len(coeffs) - 1) // 2 + 1)


def test_routh_table1_stable(table1):
    """The Table 1 characteristic polynomial passes Routh-Hurwitz; is_stable agrees."""
    r = an.routh(an.characteristic_polynomial(table1))
    assert r.stable and r.sign_changes == 0 and np.all(r.first_column > 0)
    assert an.is_stable(table1)


def test_margins_of_a_textbook_loop():
    """L = 1/(s(s+1)(s+2)): gain margin 20 log10 6 dB at sqrt(2) rad/s."""
    m = an.margins(ct.tf([1.0], [1.0, 3.0, 2.0, 0.0]))
    np.testing.assert_allclose(m.gm_db, 20 * math.log10(6.0), rtol=1e-6)
    np.testing.assert_allclose(m.wp_hz, math.sqrt(2) / (2 * math.pi), rtol=1e-6)
    wg = 0.4457  # |L(j wg)| = 1
    np.testing.assert_allclose(m.wg_hz, wg / (2 * math.pi), rtol=1e-3)
    np.testing.assert_allclose(m.pm_deg, 180 - 90 - math.degrees(math.atan(wg) + math.atan(wg / 2)),
                               rtol=1e-3)


def test_loop_margins_table1(table1):
    """Every Table 1 loop has a positive gain margin and a phase margin above 45 deg."""
    for mode in (Mode.FBC, Mode.DFBC_FFC):
        res = an.loop_margins(table1, mode)
        assert set(res) == set(mode.controllers) - {"ff_stage1"}
        for m in res.values():
            assert m.gm_db > 6.0 and m.pm_deg > 45.0


def test_excessive_gain_is_unstable(table1):
    """A 1e7 N*s/m skyhook exceeds the gain margin: closed loop unstable, gm_db < 0."""
    cfg = with_overrides(table1, {"feedback.stage1.gain": [0, 0, 1e7, 0, 0, 0]})
    assert not an.is_stable(cfg, Mode.FBC)
    assert an.loop_margins(cfg, Mode.FBC)["fb_stage1"].gm_db < 0
    assert an.is_stable(table1, Mode.FBC)


@pytest.mark.parametrize("mode", [Mode.PASSIVE, Mode.DFBC_FFC], ids=lambda m: m.value)
def test_6dof_symmetric_z_transmissibility_is_1dof(table1, mode):
    """Symmetric four-mount 6dof rig, every axis's loops closed: z equals the 1dof closed loop."""
    gains = {f"feedback.stage{i}.gain": [1e4, 2e4, table1.feedback[i - 1].gain[2], 0.0, 0.0, 0.0]
             for i in (1, 2)}
    six = config_from_flat(symmetric_6dof_flat() | gains, "<test>")
    a = an.transmissibility(six, mode, "z")
    b = an.transmissibility(table1, mode, "z")
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(an.freq_response(x, F), an.freq_response(y, F), rtol=1e-6)


def test_6dof_passive_modes_contain_the_vertical_modes(table1):
    """The symmetric 6dof rig's modes include Table 1's two vertical modes."""
    six = an.modes(config_from_flat(symmetric_6dof_flat(), "<test>"))
    for m in an.modes(table1):
        assert min(abs(x.eigenvalue_hz - m.eigenvalue_hz) for x in six) < 1e-9
