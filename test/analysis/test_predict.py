"""The model-predicted Table 4 against the analysis of long batch runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import modetable
from dcsms_ros.analysis.predict import predict_table4
from dcsms_ros.analysis.segments import SETTLE_S
from dcsms_ros.core.config import load_config
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import ALL_MODES, Mode

ROOT = Path(__file__).resolve().parents[2]
#: Seconds per mode: the Passive band RMS of a 0.15 Hz wide resonance has ~1/sqrt(T * 0.15 Hz)
#: random error (7 % at 120 s, 3 % at 600 s), and every value is divided by it.
SEGMENT_S = 600.0


@pytest.mark.slow
def test_predicted_table4_matches_the_analysis_of_batch_runs():
    """Table 1, every mode: model table4 within 10 % of the analysis definition applied to the
    measured (decoupled) top-stage velocity of a 600 s batch run per mode, as `dcsms analyze`
    reads a bag (Welch resonance, settle time, band, the whole record's band power)."""
    cfg = load_config(ROOT / "config" / "table1.yaml")
    pred = predict_table4(cfg)
    fs = cfg.plant.rate_hz
    records = {m: simulate(cfg, m, SEGMENT_S + SETTLE_S, seed=21).velocity[int(SETTLE_S * fs):,
                                                                            2, 0]
               for m in ALL_MODES}
    v = records[Mode.PASSIVE]
    f, p = est.psd(v, fs, est.choose_nperseg(fs, v.size))
    f_r = modetable.resonance_frequency(f, p ** 0.5)
    assert f_r == pytest.approx(pred.resonance_hz["z"], abs=fs / est.choose_nperseg(fs, 10**7))
    base = modetable.record_band_rms(v, fs, f_r)
    for m in ALL_MODES:
        got = modetable.record_band_rms(records[m], fs, f_r) / base
        assert got == pytest.approx(pred.values[m.label]["z"], rel=0.10), m.label


@pytest.mark.parametrize("centre_bin", [10.0, 10.3, 10.5, 9.62])
def test_refine_peak_finds_a_gaussian_vertex_between_bins(centre_bin: float) -> None:
    """A peak whose log is a parabola (a Gaussian) is located exactly from three bins."""
    f = np.arange(21) * 0.25
    asd = np.exp(-((f - centre_bin * 0.25) / 0.4) ** 2)
    i = int(np.argmax(asd))
    assert modetable.refine_peak(f, asd, i) == pytest.approx(centre_bin * 0.25, abs=1e-12)


def test_refine_peak_keeps_the_bin_at_the_edges_and_on_flat_tops() -> None:
    f = np.arange(5.0)
    assert modetable.refine_peak(f, np.array([3.0, 2, 1, 1, 1]), 0) == 0.0
    assert modetable.refine_peak(f, np.array([1.0, 2, 2, 2, 1]), 2) == 2.0


@pytest.mark.slow
def test_the_resonance_is_read_between_the_welch_bins() -> None:
    """Table 1, Passive, 24 s (the demo's segment, 0.244 Hz bins = 6.5 % of 3.77 Hz): the
    interpolated peak is within 2 % of the model's resonance in each of 6 seeds, 1 % on
    average (the nearest bin alone is off by up to half a bin, 3.2 %)."""
    cfg = load_config(ROOT / "config" / "table1.yaml")
    f_model = predict_table4(cfg).resonance_hz["z"]
    fs = cfg.plant.rate_hz
    errors = []
    for seed in range(300, 306):
        v = simulate(cfg, Mode.PASSIVE, 25.0, seed=seed).velocity[int(fs):, 2, 0]
        f, p = est.psd(v, fs, est.choose_nperseg(fs, v.size))
        assert f[1] == pytest.approx(0.244, rel=0.01)
        errors.append(abs(modetable.resonance_frequency(f, p ** 0.5) / f_model - 1.0))
    assert max(errors) < 0.02 and float(np.mean(errors)) < 0.012, errors


@pytest.mark.slow
def test_the_predicted_band_power_is_unbiased_over_seeds() -> None:
    """The one-sided 4-12 % gap between `model table4` and one seed's analysis is the shared
    Passive reference's random error, not a bias: over 16 independent seeds the band power of
    each mode averages to the model's within three standard errors, and the Passive band
    power scatters by ~20 % per 100 s run (a 0.15 Hz wide resonance: ~15 degrees of freedom),
    which every normalised value of a run divides by."""
    cfg = load_config(ROOT / "config" / "table1.yaml")
    pred = predict_table4(cfg)
    fs, f_r = cfg.plant.rate_hz, pred.resonance_hz["z"]
    modes = (Mode.PASSIVE, Mode.FBC, Mode.DFBC_FFC)
    errors = {m: [] for m in modes}
    for seed in range(400, 416):
        for m in modes:
            v = simulate(cfg, m, 101.0, seed=seed).velocity[int(fs):, 2, 0]
            power = modetable.record_band_rms(v, fs, f_r) ** 2
            errors[m].append(power / pred.band_rms_mps[m.label]["z"] ** 2 - 1.0)
    for m, e in errors.items():
        mean, se = float(np.mean(e)), float(np.std(e, ddof=1) / np.sqrt(len(e)))
        assert se < 0.07 and abs(mean) < 3.0 * se + 0.01, (m.label, mean, se)
    sd_passive = float(np.std(errors[Mode.PASSIVE], ddof=1))
    assert 0.1 < sd_passive < 0.35, sd_passive
