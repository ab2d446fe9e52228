"""`dcsms tune` end to end: bad input, an infeasible request, and the unstable fixture made safe."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from dcsms_ros.cli import main
from dcsms_ros.core.check import check_config
from dcsms_ros.core.config import load_config

ROOT = Path(__file__).resolve().parents[2]
TABLE1 = ROOT / "config" / "table1.yaml"
FIXTURE = ROOT / "test" / "fixtures" / "tem_unstable.yaml"


def _target(tmp_path: Path, doc: object) -> str:
    p = tmp_path / "target.yaml"
    p.write_text(yaml.safe_dump(doc))
    return str(p)


@pytest.mark.parametrize(("extra", "message"), [
    (["--objective", "table4"], "needs --target"),
    (["--max-evaluations", "5"], "--max-evaluations"),
    (["--objective", "table4", "--target", "TARGET:{Passive: {z: 0.5}}"], "Passive is the"),
    (["--objective", "table4", "--target", "TARGET:{FBC: {x: 0.5}}"], "axes z"),
    (["--objective", "table4", "--target", "TARGET:{FBC: {z: -1}}"], "positive number"),
    (["--objective", "table4", "--target", "TARGET:{warp: {z: 1}}"], "unknown mode"),
    (["--order", "x"], "order axes x"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, extra, message):
    extra = [_target(tmp_path, yaml.safe_load(a[7:])) if a.startswith("TARGET:") else a
             for a in extra]
    out = tmp_path / "out.yaml"
    assert main(["tune", "--config", str(TABLE1), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert not out.exists()


def test_existing_output_is_never_overwritten(tmp_path, capsys):
    out = tmp_path / "mine.yaml"
    out.write_text("keep")
    assert main(["tune", "--config", str(TABLE1), "--out", str(out)]) == 2
    assert "not overwriting" in capsys.readouterr().err
    assert out.read_text() == "keep"


def test_an_output_in_a_missing_directory_is_refused_before_the_tune(tmp_path, capsys):
    """Found before minutes of tuning, not when the result is written: exit 2, one line."""
    out = tmp_path / "missing" / "out.yaml"
    assert main(["tune", "--config", str(TABLE1), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not a directory" in err[0], err
    assert not (tmp_path / "missing").exists()


@pytest.mark.slow
def test_impossible_forces_exit_1_and_write_nothing(tmp_path, capsys):
    """1 uN actuators: even the least feedback gain (10 N s/m) on a um/s table needs more than
    a quarter of that, so no candidate is feasible."""
    out = tmp_path / "out.yaml"
    status = main(["tune", "--config", str(TABLE1), "--out", str(out), "--set",
                   "actuators.force_limit_n=1e-6", "--max-evaluations", "20",
                   "--check-seconds", "0"])
    assert status == 1
    assert "no candidate met every constraint" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("*.partial"))


@pytest.mark.slow
def test_table1_result_is_a_loadable_checked_params_file(tmp_path, capsys):
    """Attenuation on Table 1: the file loads, says how it was made, passes the check, and the
    printed table has the batch run beside the prediction."""
    out = tmp_path / "tuned.yaml"
    assert main(["tune", "--config", str(TABLE1), "--out", str(out), "--max-evaluations", "30",
                 "--check-seconds", "4"]) == 0
    text = capsys.readouterr().out
    assert "Z predicted" in text and "Z simulated" in text and "0 saturated" in text
    head = out.read_text().splitlines()[0]
    assert head.startswith("# Written by `dcsms tune --objective attenuation`")
    cfg = load_config(out)
    assert all(c.ok for c in check_config(cfg))
    assert main(["model", "check", "--config", str(out)]) == 0


@pytest.mark.slow
def test_tune_makes_the_unstable_fixture_safe(tmp_path, capsys):
    """The fixture (DFBC unstable through the sensor chain) with --corners: a configuration
    that `dcsms model check` passes."""
    assert main(["model", "check", "--config", str(FIXTURE)]) == 1
    out = tmp_path / "safe.yaml"
    assert main(["tune", "--config", str(FIXTURE), "--out", str(out), "--corners",
                 "--max-evaluations", "60", "--check-seconds", "0"]) == 0, \
        capsys.readouterr().err
    assert main(["model", "check", "--config", str(out)]) == 0
