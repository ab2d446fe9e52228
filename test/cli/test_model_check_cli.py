"""``dcsms model check``, ``table4`` and the loop-as-it-runs ``eig``: verdicts and exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dcsms_ros.cli import main
from dcsms_ros.core.config import load_config
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "test" / "fixtures" / "tem_unstable.yaml"
PRESETS = sorted((ROOT / "config").glob("*.yaml"))


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


@pytest.mark.slow
def test_check_refuses_the_unstable_fixture(capsys):
    """Exit 1, naming DFBC and DFBC+FFC as unstable with their pole; the other modes pass."""
    status, out, err = run(capsys, "model", "check", "--config", str(FIXTURE))
    assert status == 1
    assert "FAIL (DFBC, DFBC+FFC)" in err
    for label in ("DFBC", "DFBC+FFC"):
        assert f"{label}: unstable: pole +0.0576 +0.4249j Hz" in out
    rows = {line.split()[0]: line.split()[-1] for line in out.splitlines()
            if line.split() and line.split()[0] in {"Passive", "FBC", "FFC", "FBC+FFC",
                                                     "DFBC", "DFBC+FFC"}}
    assert rows == {"Passive": "OK", "FBC": "OK", "FFC": "OK", "FBC+FFC": "OK",
                    "DFBC": "FAIL", "DFBC+FFC": "FAIL"}


@pytest.mark.parametrize("preset", PRESETS, ids=lambda p: p.name)
@pytest.mark.slow
def test_check_passes_every_shipped_preset(capsys, preset):
    """Every shipped preset is stable in all six modes with >= 6 dB / 30 deg and unsaturated."""
    status, out, _ = run(capsys, "model", "check", "--config", str(preset), "--json")
    doc = json.loads(out)
    assert status == 0 and doc["ok"] is True, [m["failures"] for m in doc["modes"].values()]
    assert list(doc["modes"]) == ["Passive", "FBC", "FFC", "FBC+FFC", "DFBC", "DFBC+FFC"]
    for m in doc["modes"].values():
        assert m["stable"] and all(a["peak_n"] <= a["limit_n"] for a in m["actuators"].values())
        assert all(abs(lp["gm_db"]) >= 6 and lp["pm_deg"] >= 30 for lp in m["loops"]
                   if lp["gm_db"] is not None and lp["pm_deg"] is not None)


def test_check_minimum_margins_and_bad_input(capsys):
    """A stricter --min-gm fails a preset (exit 1, the loop named); bad input exits 2."""
    status, out, _ = run(capsys, "model", "check", "--min-gm", "30")
    assert status == 1 and "fb_stage2.z margins" in out and "below 30 dB" in out
    status, out, err = run(capsys, "model", "check", "--set", "m1=-5")
    assert status == 2 and out == "" and len(err.strip().splitlines()) == 1
    status, _, err = run(capsys, "model", "check", "--min-pm", "nan")
    assert status == 2 and "--min-gm and --min-pm" in err


def test_eig_of_the_fixture_is_unstable_with_the_simulated_growth(capsys):
    """eig --json on the fixture in DFBC: stable false; the worst pole's real part (Hz) equals
    the growth of the batch run's stage-2 envelope within 10 %."""
    status, out, _ = run(capsys, "model", "eig", "--config", str(FIXTURE), "--mode", "DFBC",
                         "--json")
    doc = json.loads(out)
    assert status == 0 and doc["model"] == "discrete" and doc["stable"] is False
    re_hz = doc["worst_pole"]["eigenvalue_hz"][0]
    assert re_hz > 0 and doc["unstable_poles"]
    res = simulate(load_config(FIXTURE), Mode.DFBC, 24.0, seed=2, trip=False)
    v = res.truth[:, 2, 1]
    w = 2000
    r = np.sqrt(np.mean(v[: v.size // w * w].reshape(-1, w) ** 2, axis=1))
    sel = r > 20 * r[0]
    slope = np.polyfit(np.arange(r.size)[sel] + 0.5, np.log(r[sel]), 1)[0]
    assert slope / (2 * np.pi) == pytest.approx(re_hz, rel=0.10)


def test_eig_ideal_keeps_the_papers_eq9(capsys):
    """--ideal is the paper's continuous model: Eq. 9 for Table 1; the default lists the plant
    modes among the sensor poles with the same values (exact ZOH)."""
    status, out, _ = run(capsys, "model", "eig", "--ideal", "--json")
    doc = json.loads(out)
    assert status == 0 and doc["model"] == "ideal" and doc["stable"] is True
    got = [m["eigenvalue_hz"] for m in doc["modes"]]
    assert got == [[pytest.approx(-0.0729, abs=5e-5), pytest.approx(3.7677, abs=5e-5)],
                   [pytest.approx(-0.4509, abs=5e-5), pytest.approx(9.3633, abs=5e-5)]]
    status, out, _ = run(capsys, "model", "eig", "--json")
    plant = [m["eigenvalue_hz"] for m in json.loads(out)["modes"] if m["part"] == "plant"]
    assert plant == [[pytest.approx(a, abs=1e-9) for a in x] for x in got]


@pytest.mark.slow
def test_table4_json_shape(capsys):
    """table4 --json is exactly {reference, resonance_hz, modes}; the paper's Z ordering."""
    status, out, _ = run(capsys, "model", "table4", "--json")
    doc = json.loads(out)
    assert status == 0 and list(doc) == ["reference", "resonance_hz", "modes"]
    assert doc["reference"] == "Passive" and list(doc["resonance_hz"]) == ["z"]
    assert 3.5 < doc["resonance_hz"]["z"] < 4.0
    z = {m: v["z"] for m, v in doc["modes"].items()}
    assert z["Passive"] == 1.0
    assert z["FBC"] > z["FBC+FFC"] > z["DFBC"] > z["DFBC+FFC"]
    status, out, _ = run(capsys, "model", "table4", "--config", str(FIXTURE), "--json")
    modes = json.loads(out)["modes"]
    assert status == 0 and modes["DFBC"] == {"x": None, "y": None, "z": None}
