"""The ground-corrected Table-4 estimator (:mod:`dcsms_ros.analysis.groundnorm`) against the
plain one and the loop model, on the batch engine."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import modetable
from dcsms_ros.analysis.groundnorm import band_power_cv, normalized_cv
from dcsms_ros.analysis.predict import predict_table4
from dcsms_ros.core.config import load_config
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode

TABLE1 = Path(__file__).resolve().parents[2] / "config" / "table1.yaml"


def test_the_correction_vanishes_when_the_floor_matches_the_common_spectrum() -> None:
    rng = np.random.default_rng(1)
    f = np.linspace(0.0, 10.0, 41)
    top, ground = rng.uniform(1, 2, f.size), rng.uniform(1, 2, f.size)
    h1 = rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)
    assert_allclose(band_power_cv(f, top, ground, h1, ground, 4.0),
                    modetable.resonance_band_rms(f, top, 4.0) ** 2)


@pytest.mark.slow
def test_lower_scatter_and_the_models_value_over_seeds() -> None:
    """Table1, Passive and DFBC, 24 s analysed per segment, 16 seeds: the corrected value
    scatters less than the plain one, the two agree on average (the same quantity), and their
    median is within 20 % of the model's prediction at the model's resonance."""
    cfg = load_config(TABLE1)
    fs, top = cfg.plant.rate_hz, cfg.plant.num_stages
    model = predict_table4(cfg, [Mode.PASSIVE, Mode.DFBC])
    f_r = model.resonance_hz["z"]
    plain, corrected = [], []
    for s in range(16):
        segs = []
        for i, m in enumerate((Mode.PASSIVE, Mode.DFBC)):
            v = simulate(cfg, m, 33.0, seed=900 + 10 * s + i).velocity[int(9 * fs):]
            g, t = (np.ascontiguousarray(v[:, k, 0]) for k in (0, top))
            f, (pg, pt, pgt), _ = est.welch_sums(g, t, fs, est.choose_nperseg(fs, t.size))
            segs.append((pt, pg, pgt / pg))
        corrected.append(normalized_cv(segs, f, f_r)[1])
        plain.append(modetable.resonance_band_rms(f, segs[1][0], f_r)
                     / modetable.resonance_band_rms(f, segs[0][0], f_r))
    plain_a, cv_a = np.array(plain), np.array(corrected)
    assert cv_a.std(ddof=1) < plain_a.std(ddof=1)
    diff = cv_a - plain_a
    assert abs(diff.mean()) < 3 * diff.std(ddof=1) / np.sqrt(diff.size)
    assert_allclose(np.median(cv_a), model.values["DFBC"]["z"], rtol=0.2)
