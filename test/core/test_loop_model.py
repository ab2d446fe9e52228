"""The discrete loop model is the loop the batch engine runs: impulse responses, growth, spectra."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import signal

from dcsms_ros.core.check import stability
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.filters import feedback_tf, feedforward_tf, to_sos
from dcsms_ros.core.loop_model import Response, loop_model
from dcsms_ros.core.modes import ALL_MODES, Mode
from dcsms_ros.core.sosfilter import SosFilter, sos_state_space
from dcsms_ros.core.spectra import rms, shaped

ROOT = Path(__file__).resolve().parents[2]
PRESETS = ["table1.yaml", "prototype.yaml", "tem_three_point.yaml"]
UNSTABLE = ROOT / "test" / "fixtures" / "tem_unstable.yaml"
QUIET = {"sensors.noise_asd": 0.0, "disturbance.ground_rms_mps": [0.0, 0.0, 0.0],
         "disturbance.force_rms_n": 0.0}


def _run_model(model, u: np.ndarray) -> np.ndarray:
    """Step ``x[k+1] = a x + b u``, ``y = c x + d u`` over the rows of ``u``."""
    x = np.zeros(model.nstates)
    y = np.empty((u.shape[0], model.c.shape[0]))
    for k in range(u.shape[0]):
        y[k] = model.c @ x + model.d @ u[k]
        x = model.a @ x + model.b @ u[k]
    return y


@pytest.mark.parametrize("fb", [(0.3, 1, 150.0, 2, 0.0, 0.0, 0.0),
                                (0.5, 2, 80.0, 4, 12.0, 3.0, 8.0)])
def test_sos_state_space_steps_like_the_filter(fb):
    """The state-space form of a filter's sections gives its output to rounding."""
    cfg = load_config(ROOT / "config" / "table1.yaml")
    hp, hpo, lp, lpo, lead, lag, notch = fb
    tfb = feedback_tf(cfg.feedback[0].__class__((0, 0, 1e4, 0, 0, 0), hp, hpo, lp, lpo, notch,
                                                5.0, lead, lag), 2)
    for tf in (tfb, feedforward_tf(cfg.feedforward, 1960.0, 1.2e6)):
        f = SosFilter(to_sos(tf, 2000.0), 1)
        a, b, c, d = sos_state_space(f.coefficients()[0])
        x = np.random.default_rng(1).standard_normal(3000)
        z = np.zeros(a.shape[0])
        y = np.empty_like(x)
        for k, u in enumerate(x):
            y[k] = (c @ z)[0] + d[0, 0] * u
            z = a @ z + b[:, 0] * u
        ref = f.run(x[:, None])[:, 0]
        assert_allclose(y, ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))


def _impulses(cfg, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """An impulse on the ground (sample 0) and on each table (later samples), every driven axis
    with its own amplitude: (ground (K, dof), table (K, N, dof))."""
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    axes = [0] if dof == 1 else [0, 1, 2]
    ground = np.zeros((steps, dof))
    table = np.zeros((steps, n, dof))
    for j, a in enumerate(axes):
        ground[0, a] = 1e-5 * (1 + j)
        for i in range(n):
            table[150 * (i + 1), i, a] = 0.5 * (1 + j) * (i + 1)
    return ground, table


@pytest.mark.parametrize("mode", ALL_MODES, ids=lambda m: m.value)
@pytest.mark.parametrize("preset", [*PRESETS, "fixture:tem_unstable"])
def test_model_impulse_response_equals_batch_engine(preset, mode):
    """Ground and table impulses, noise and disturbances off: the model's stage velocities,
    decoupled velocities and actuator forces equal the batch engine's to 1e-9 (relative to each
    signal's peak), for every shipped preset, the unstable fixture and every mode."""
    path = UNSTABLE if preset.startswith("fixture") else ROOT / "config" / preset
    cfg = with_overrides(load_config(path), QUIET)
    steps = 1600
    ground, table = _impulses(cfg, steps)
    res = simulate(cfg, mode, steps / cfg.plant.rate_hz, ground=ground, table=table, trip=False)
    model = loop_model(cfg, mode)
    u = np.zeros((steps, model.b.shape[1]))
    u[:, model.inputs["ground"]] = ground
    u[:, model.inputs["table"]] = table.reshape(steps, -1)
    y = _run_model(model, u)
    n, dof = cfg.plant.num_stages, cfg.plant.dof
    pairs = {"stage": res.truth[:, 1:].reshape(steps, n * dof),
             "velocity": res.velocity.reshape(steps, -1), "force": res.applied}
    for name, sim in pairs.items():
        got = y[:, model.outputs[name]]
        scale = max(float(np.max(np.abs(sim))), 1e-300)
        assert np.max(np.abs(got - sim)) <= 1e-9 * scale, name
    assert res.counters["saturations"] == 0


def _envelope_growth(v: np.ndarray, fs: float, window_s: float = 1.0) -> tuple[float, float]:
    """Slope (1/s) of log RMS in consecutive windows over the stretch where the growth
    dominates (RMS above 20 x its first window), and that stretch's length (s)."""
    w = int(window_s * fs)
    r = np.sqrt(np.mean(v[: v.size // w * w].reshape(-1, w) ** 2, axis=1))
    t = (np.arange(r.size) + 0.5) * window_s
    sel = r > 20.0 * r[0]
    slope = np.polyfit(t[sel], np.log(r[sel]), 1)[0]
    return float(slope), float(sel.sum() * window_s)


def test_unstable_fixture_growth_equals_simulated_envelope():
    """The worst pole of the unstable fixture in DFBC grows as the batch run's envelope does
    (within 10 %); its real part is positive; nothing saturates meanwhile."""
    cfg = load_config(UNSTABLE)
    st = stability(cfg, Mode.DFBC)
    assert not st.stable and st.worst_s_hz.real > 0.0
    res = simulate(cfg, Mode.DFBC, 24.0, seed=4, trip=False)
    assert res.counters["saturations"] == 0
    slope, span = _envelope_growth(res.truth[:, 2, 0], cfg.plant.rate_hz)
    assert span >= 5.0
    assert slope == pytest.approx(st.growth_per_s, rel=0.10)
    assert st.growth_per_s == pytest.approx(2 * math.pi * st.worst_s_hz.real)


def _welch_expected(model_psd, f: np.ndarray, fs: float, nperseg: int) -> np.ndarray:
    """E[Welch] of a process with PSD ``model_psd`` (f -> (F, n)): the PSD convolved with the
    Hann window's spectral kernel (|W|^2 normalised to unit area), +-4 bins at 1/6-bin steps;
    shape (F, n)."""
    win = signal.get_window("hann", nperseg)
    off = np.arange(-24, 25) / 6.0 * fs / nperseg
    k = np.exp(-2j * np.pi * np.outer(off, np.arange(nperseg)) / fs) @ win
    kern = np.abs(k) ** 2
    kern /= kern.sum()
    p = model_psd(np.abs((f[:, None] + off[None, :]).ravel()))
    return np.einsum("fkn,k->fn", p.reshape(f.size, off.size, -1), kern)


@pytest.mark.parametrize(("preset", "mode"), [("table1.yaml", Mode.PASSIVE),
                                              ("table1.yaml", Mode.DFBC_FFC),
                                              ("tem_three_point.yaml", Mode.FBC_FFC)])
@pytest.mark.slow
def test_predicted_psd_matches_batch_welch(preset, mode):
    """The PSD of each stage velocity predicted from the configured ground, table-force and
    sensor-noise spectra matches the batch engine's Welch PSD within 1 dB over 1-100 Hz,
    smoothed over 5 bins (random error ~0.15 dB there), and the predicted RMS of every stage
    velocity and actuator force matches the simulated one within 3 standard errors (estimated
    from 10 batch means: the TEM's variance sits partly in modes 0.03 Hz wide and, for the
    forces, in the boosted low-frequency sensor noise, so 200 s hold few independent samples of
    it) plus 2 %."""
    cfg = load_config(ROOT / "config" / preset)
    fs = cfg.plant.rate_hz
    duration = 600.0 if cfg.plant.dof == 1 else 200.0
    res = simulate(cfg, mode, duration, seed=8)
    model = shaped(cfg, loop_model(cfg, mode))
    nper = 8192
    dof, n = cfg.plant.dof, cfg.plant.num_stages
    axis = 2 if dof == 6 else 0
    skip = int(2 * fs)
    rows = [model.outputs["stage"].start + i * dof + axis for i in range(n)]
    resp = Response(model.select(slice(0, model.b.shape[1]), rows))
    f, p_sim = signal.welch(res.truth[skip:, 1:, axis], fs=fs, nperseg=nper, axis=0)
    sel = (f >= 1.0) & (f <= 100.0)
    p_mod = _welch_expected(lambda x: 2 * model.dt * np.sum(np.abs(resp(x)) ** 2, axis=2),
                            f[sel], fs, nper)
    smooth = np.ones(5) / 5
    for i in range(n):
        err_db = 10 * np.log10(np.convolve(p_sim[sel, i], smooth, "valid")
                               / np.convolve(p_mod[:, i], smooth, "valid"))
        assert np.max(np.abs(err_db)) < 1.0, (i, float(np.max(np.abs(err_db))))
    want = rms(model)
    for name, x in (("force", res.applied[skip:]),
                    ("stage", res.truth[skip:, 1:].reshape(-1, n * dof))):
        w = want[model.outputs[name]]
        got = x.std(axis=0)
        # standard error of the RMS from the scatter of 10 batch means of the variance
        var = np.array([c.var(axis=0) for c in np.array_split(x, 10)])
        err = var.std(axis=0, ddof=1) / np.sqrt(10) / (2 * np.maximum(got, 1e-300))
        # channels the disturbances barely reach (rounding-level RMS) are only checked as such
        big = w > 1e-3 * np.max(w)
        assert np.all(np.abs(got - w)[big] <= 3 * err[big] + 0.02 * w[big]), (name, got, w, err)
        assert np.all(got[~big] <= 2e-3 * np.max(w)), name
