"""``dcsms fit``: a changed plant identified from a batch run with an excitation; what the
data cannot identify is refused with one line and exit 2."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
from true_plant import TRUE_PLANT

from dcsms_ros.analysis import identify, identify_fit
from dcsms_ros.analysis.export import write_result_bag
from dcsms_ros.cli import main
from dcsms_ros.cli.common import default_config_path
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.excitation import excitation_signal, parse_spec
from dcsms_ros.core.modes import Mode

# every test here reads bags of 20-60 s runs made by session fixtures
pytestmark = pytest.mark.slow

CFG = load_config(default_config_path())
PRESET = {"m1": 988.8, "m2": 748.8, "k1": 1.2e6, "k2": 1.2e6, "c1": 1960.0, "c2": 1960.0}


@pytest.fixture(scope="module")
def fitted(excited_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("fit") / "out"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["fit", str(excited_bag), "--json", "--out", str(out)]) == 0
    return json.loads(buf.getvalue()), out


def test_fit_identifies_the_changed_plant(fitted: tuple[dict, Path]) -> None:
    """Passive, 5 N RMS white noise on stage 1, m1 +10 %, k2 -15 %, c1 +50 % against the
    recorded preset: masses and stiffnesses within 3 %, dampings within 10 %; each error
    within 4 standard deviations (the stds are honest); the residual falls to the scatter."""
    doc, _ = fitted
    params = doc["parameters"]
    assert set(params) == set(TRUE_PLANT)
    for name, truth in TRUE_PLANT.items():
        p = params[name]
        tol = 0.10 if name.startswith("c") else 0.03
        np.testing.assert_allclose(p["value"], truth, rtol=tol, err_msg=name)
        assert p["std"] > 0 and abs(p["value"] - truth) < 4 * p["std"] + 1e-3 * truth, name
        assert p["start"] == PRESET[name]  # the fit starts from the recorded configuration
    assert doc["residual_db_start"] > 1.5 and doc["residual_db"] < 0.5
    assert 0.7 < doc["chi2_reduced"] < 1.5
    assert doc["bins"] > 500


def test_fit_writes_params_plots_and_json(fitted: tuple[dict, Path]) -> None:
    """fit.yaml is a params file with the fitted values that loads as --config; the plot and
    fit.json are written."""
    doc, out = fitted
    cfg = load_config(out / "fit.yaml")
    assert cfg.plant.stages[0].mass == pytest.approx(doc["parameters"]["m1"]["value"])
    assert cfg.plant.stages[1].stiffness == pytest.approx(doc["parameters"]["k2"]["value"])
    assert cfg.feedback == CFG.feedback  # only the fitted values changed
    assert json.loads((out / "fit.json").read_text())["parameters"] == doc["parameters"]
    assert (out / "fit_mobility_z.png").stat().st_size > 10_000


def test_fit_subset_and_start(excited_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A subset of parameters from a given start converges to the same values (table output)."""
    assert main(["fit", str(excited_bag), "--params", "m1,c1", "--start", "m1=900"]) == 0
    text = capsys.readouterr().out
    row = next(line.split() for line in text.splitlines() if line.startswith("m1 "))
    assert float(row[1]) == 900.0
    assert float(row[2]) == pytest.approx(TRUE_PLANT["m1"], rel=0.03)


@pytest.fixture(scope="module")
def quiet_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 s Passive without excitation."""
    out = tmp_path_factory.mktemp("quiet") / "bag"
    assert main(["sim", "--duration", "20", "--seed", "2", "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("bag, extra, message", [
    ("quiet", [], "without a force excitation"),
    ("quiet", ["--params", "fg,zg"], "cancel in a transmissibility"),
    ("excited", ["--params", "m1,m2,k1,k2,c1,c2,sg"], "scaling all of them"),
    ("excited", ["--params", "k1x"], "a 1dof plant has no axes"),
    ("excited", ["--params", "q7"], "unknown parameter 'q7'"),
    ("excited", ["--params", "m3"], "stage3 does not exist"),
    ("excited", ["--params", "m1,m1"], "given twice"),
    ("excited", ["--params", "m1", "--start", "k1=5"], "not among the fitted"),
    ("excited", ["--start", "m1=-5"], "VALUE > 0"),
    ("excited", ["--use", "phase"], "--use"),
    ("excited", ["--use", "transmissibility"], "no usable bins"),
])
def test_unidentifiable_is_refused(bag: str, extra: list[str], message: str,
                                   excited_bag: Path, quiet_bag: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    """What the data cannot identify: one line, exit 2."""
    path = excited_bag if bag == "excited" else quiet_bag
    assert main(["fit", str(path), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("dcsms: error:") and message in err[-1], err


def test_transmissibility_fits_ratios_with_one_parameter_fixed(quiet_bag: Path) -> None:
    """Without an excitation every mass, stiffness and damping cannot be fitted, but with the
    masses known the suspensions are identified from the transmissibility alone (the plant is
    the preset here: the fit stays there)."""
    col = identify.collect([quiet_bag])
    res = identify_fit.fit(col, identify.parse_params(col.cfg, "k1,k2,c1,c2"),
                       start={"k1": 1.1e6, "c2": 2500.0})
    np.testing.assert_allclose(res.value[:2], [1.2e6, 1.2e6], rtol=0.05)


def _scaled_readings_bag(path: Path, scale: float, mode: Mode, seconds: float) -> Path:
    """A run whose decoupled velocities read ``scale`` times the truth: a geophone whose true
    sensitivity is ``scale`` times the configured one."""
    spec = [parse_spec("stage1.z:white:5")]
    n = int(seconds * 2000)
    res = simulate(CFG, mode, seconds, seed=4, excite=excitation_signal(CFG, spec, n, 4))
    res.velocity *= scale
    res.raw *= scale
    write_result_bag(res, path)
    return path


def test_sensitivity_from_a_passive_mobility(tmp_path: Path) -> None:
    """Readings 4 % high (true sensitivity 104.416 V/(m/s) against the configured 100.4): sg
    is identified with the masses known."""
    bag = _scaled_readings_bag(tmp_path / "s", 1.04, Mode.PASSIVE, 20.0)
    col = identify.collect([bag])
    res = identify_fit.fit(col, identify.parse_params(col.cfg, "sg,k1,c1"))
    assert res.value[0] == pytest.approx(100.4 * 1.04, rel=0.005)


def test_sensitivity_refused_in_closed_loop(tmp_path: Path) -> None:
    bag = _scaled_readings_bag(tmp_path / "c", 1.0, Mode.FBC, 6.0)
    col = identify.collect([bag])
    with pytest.raises(identify.DcsmsError, match="from FBC segments"):
        identify_fit.fit(col, identify.parse_params(col.cfg, "sg,k1"))


def test_geophone_dynamics_from_the_mobility(tmp_path: Path) -> None:
    """Geophones at 4.0 Hz / 0.5 where the rig's configuration says 4.5 Hz / 0.42: the
    decoupled velocities carry the mismatch, and fg, zg are identified (with m1, c1)."""
    plant = with_overrides(CFG, {"sensors.natural_frequency_hz": 4.0,
                                 "sensors.damping_ratio": 0.5})
    spec = [parse_spec("stage1.z:white:5")]
    res = simulate(CFG, Mode.PASSIVE, 30.0, seed=6, plant=plant,
                   excite=excitation_signal(CFG, spec, 60_000, 6))
    write_result_bag(res, tmp_path / "g")
    col = identify.collect([tmp_path / "g"])
    fit = identify_fit.fit(col, identify.parse_params(col.cfg, "fg,zg,m1,c1"))
    np.testing.assert_allclose(fit.value[:2], [4.0, 0.5], rtol=0.03)
    assert fit.value[2] == pytest.approx(988.8, rel=0.03)
    assert fit.value[3] == pytest.approx(1960.0, rel=0.10)


def test_sixdof_suspension_per_axis(tmp_path: Path) -> None:
    """6-DOF (the TEM preset): the stage-1 mounts 10 % softer and 30 % more damped along x;
    a 20 N RMS excitation along x on stage 1 identifies k1x and c1x (each mount's x value
    scaled alike)."""
    cfg = load_config(default_config_path().parent / "tem_three_point.yaml")
    params = identify.parse_params(cfg, "k1x,c1x")
    flat = dict(cfg.params or {})
    truth = [params[0].value(cfg) * 0.9, params[1].value(cfg) * 1.3]
    for p, v in zip(params, truth, strict=True):
        p.write(flat, cfg, v)
    plant = with_overrides(cfg, {k: flat[k] for k in ("stage1.mounts.stiffness",
                                                       "stage1.mounts.damping")})
    spec = [parse_spec("stage1.x:white:20")]
    res = simulate(cfg, Mode.PASSIVE, 20.0, seed=3, plant=plant,
                   excite=excitation_signal(cfg, spec, 40_000, 3))
    write_result_bag(res, tmp_path / "six")
    col = identify.collect([tmp_path / "six"])
    fit = identify_fit.fit(col, params)
    assert fit.value[0] == pytest.approx(truth[0], rel=0.03)
    assert fit.value[1] == pytest.approx(truth[1], rel=0.10)


@pytest.mark.parametrize("names, message", [("k1", "fitted per axis"), ("c2", "per axis"),
                                            ("m1x", "a mass has no axis")])
def test_sixdof_names(names: str, message: str) -> None:
    cfg = load_config(default_config_path().parent / "tem_three_point.yaml")
    with pytest.raises(identify.DcsmsError, match=message):
        identify.parse_params(cfg, names)
    assert [p.name for p in identify.parse_params(cfg, None)][:3] == ["k1x", "k1y", "k1z"]
