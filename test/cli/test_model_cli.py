"""The ``dcsms`` command: ``model eig|routh|tf|sweep``, ``params`` and the error conventions."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dcsms_ros import cli
from dcsms_ros.cli import main
from dcsms_ros.cli.model import parse_factors

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: NOTES.md, Eq. 9 (eigenvalues / 2 pi, Hz) and the exact 2-DOF frequencies / damping ratios.
EQ9 = [(-0.0729, 3.7677, 3.7684, 1.934e-2), (-0.4509, 9.3633, 9.3741, 4.810e-2)]


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """``main(argv)`` in-process: (exit status, stdout, stderr)."""
    status = main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def test_eig_json_reproduces_eq9(capsys: pytest.CaptureFixture[str]) -> None:
    """eig --ideal --json gives the paper's Eq. 9 eigenvalues to the printed 4 decimals."""
    status, out, _ = run(capsys, "model", "eig", "--ideal", "--json")
    assert status == 0
    doc = json.loads(out)
    assert list(doc) == ["model", "mode", "stable", "worst_pole", "unstable_poles", "modes"]
    assert doc["stable"] is True and doc["unstable_poles"] == []
    assert len(doc["modes"]) == len(EQ9)
    for mode, (re, im, f, zeta) in zip(doc["modes"], EQ9, strict=True):
        assert list(mode) == ["eigenvalue_hz", "frequency_hz", "damping_ratio"]
        assert mode["eigenvalue_hz"] == [pytest.approx(re, abs=5e-5), pytest.approx(im, abs=5e-5)]
        assert mode["frequency_hz"] == pytest.approx(f, abs=5e-5)
        assert mode["damping_ratio"] == pytest.approx(zeta, abs=5e-6)


def test_eig_table_and_closed_loop(capsys: pytest.CaptureFixture[str]) -> None:
    """The plain table lists both passive modes; --mode gives a stable closed loop."""
    status, out, _ = run(capsys, "model", "eig")
    assert status == 0
    assert "3.7677i" in out and "9.3633i" in out and "stable" in out
    status, out, _ = run(capsys, "model", "eig", "--mode", "DFBC+FFC", "--json")
    assert status == 0 and json.loads(out)["stable"] is True


def test_routh_array_and_verdict(capsys: pytest.CaptureFixture[str]) -> None:
    """routh prints rows s^4 .. s^0 and 'stable' for Table 1; --coeffs can be unstable."""
    status, out, _ = run(capsys, "model", "routh")
    assert status == 0
    assert all(f"s^{p}" in out for p in range(5)) and "0 sign changes -> stable" in out
    status, out, _ = run(capsys, "model", "routh", "--coeffs", "1,-1,1", "--json")
    doc = json.loads(out)
    assert status == 0 and doc["stable"] is False and doc["sign_changes"] == 2


def test_tf_json_and_margins(capsys: pytest.CaptureFixture[str]) -> None:
    """tf --json has both stages on the grid and margins of both feedback loops."""
    status, out, _ = run(capsys, "model", "tf", "--mode", "DFBC+FFC", "--points", "60", "--json")
    assert status == 0
    doc = json.loads(out)
    assert doc["mode"] == "DFBC+FFC" and len(doc["frequency_hz"]) == 60
    assert set(doc["transmissibility"]) == {"v_p1/v_b", "v_p2/v_b"}
    assert all(len(v["magnitude_db"]) == 60 for v in doc["transmissibility"].values())
    assert set(doc["margins"]) == {"fb_stage1", "fb_stage2"}
    # the active loops flatten the passive resonance peak (29 dB at 3.8 Hz)
    assert max(doc["transmissibility"]["v_p2/v_b"]["magnitude_db"]) < 10.0


def test_tf_plot_writes_bode_png(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """tf --plot writes a Bode PNG named after mode and axis."""
    status, _, _ = run(capsys, "model", "tf", "--mode", "fbc", "--points", "40",
                       "--plot", str(tmp_path))
    assert status == 0
    assert (tmp_path / "bode_fbc_z.png").read_bytes().startswith(PNG_MAGIC)


def test_sweep_writes_fig3_and_fig6(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """sweep --plot writes fig3_<param>.png and fig6_<param>.png."""
    status, out, _ = run(capsys, "model", "sweep", "--param", "c1", "--factors", "1:41:20",
                         "--points", "60", "--plot", str(tmp_path))
    assert status == 0
    for name in ("fig3_c1.png", "fig6_c1.png"):
        assert (tmp_path / name).read_bytes().startswith(PNG_MAGIC)
    assert "stage1.damping" in out


def test_sweep_json_loci(capsys: pytest.CaptureFixture[str]) -> None:
    """sweep --json: 4 eigenvalues per factor; raising k2 raises the top mode frequency."""
    status, out, _ = run(capsys, "model", "sweep", "--param", "k2", "--factors", "0.5,1,2",
                         "--points", "20", "--json")
    assert status == 0
    doc = json.loads(out)
    assert doc["name"] == "stage2.stiffness" and doc["factors"] == [0.5, 1.0, 2.0]
    assert [len(x) for x in doc["eigenvalues_hz"]] == [4, 4, 4]
    top = [ms[-1]["frequency_hz"] for ms in doc["modes"]]
    assert top == sorted(top)


def test_parse_factors() -> None:
    """start:stop:step includes stop and does not accumulate rounding; lists are kept."""
    f = parse_factors("1:101:2")
    assert len(f) == 51 and f[0] == 1.0 and f[-1] == 101.0
    f = parse_factors("0.1:10:0.1")
    assert len(f) == 100 and f[-1] == 10.0
    assert parse_factors("0.5,1,2") == [0.5, 1.0, 2.0]


def test_bad_override_exits_2_naming_field(capsys: pytest.CaptureFixture[str]) -> None:
    """--set m1=-1 exits 2 with one line on stderr naming stage1.mass."""
    status, out, err = run(capsys, "model", "eig", "--set", "m1=-1")
    assert status == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("dcsms: error:") and "stage1.mass" in lines[0]


def test_unknown_sweep_param_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    """An unknown --param is a usage error (exit 2) that names it."""
    status, _, err = run(capsys, "model", "sweep", "--param", "q7", "--factors", "1,2")
    assert status == 2 and "q7" in err
    status, _, err = run(capsys, "model", "sweep", "--param", "m3", "--factors", "1,2")
    assert status == 2 and "m3" in err  # valid form, but there is no stage 3


def test_missing_config_and_bad_factors_exit_2(capsys: pytest.CaptureFixture[str],
                                               tmp_path: Path) -> None:
    """A missing --config file and a malformed --factors both exit 2."""
    status, _, err = run(capsys, "model", "eig", "--config", str(tmp_path / "nope.yaml"))
    assert status == 2 and "nope.yaml" in err
    status, _, _ = run(capsys, "model", "sweep", "--param", "c1", "--factors", "5:1:1")
    assert status == 2


def test_missing_subcommand_module_is_skipped(monkeypatch: pytest.MonkeyPatch) -> None:
    """A sub-command module that does not exist is skipped; the rest still register."""
    monkeypatch.setattr(cli, "SUBCOMMANDS", ("params", "no_such_command"))
    parser = cli.build_parser()
    assert parser.parse_args(["params"]).command == "params"


def test_import_error_inside_module_surfaces(monkeypatch: pytest.MonkeyPatch) -> None:
    """A missing dependency inside an existing sub-command module is not swallowed."""
    def broken(name: str) -> None:
        raise ModuleNotFoundError("No module named 'somedep'", name="somedep")

    monkeypatch.setattr(cli.importlib, "import_module", broken)
    with pytest.raises(ModuleNotFoundError):
        cli.build_parser()


def test_keyboard_interrupt_exits_130(capsys: pytest.CaptureFixture[str],
                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C during a command exits 130 without a traceback."""
    from dcsms_ros.cli import model_eig

    def interrupted(args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(model_eig, "run", interrupted)
    status, _, err = run(capsys, "model", "eig")
    assert status == 130 and err == ""


@pytest.mark.slow
def test_installed_console_script(tmp_path: Path) -> None:
    """The installed ``dcsms`` console script runs eig --ideal --json from any directory."""
    exe = Path(sys.executable).parent / "dcsms"
    if not exe.is_file():
        pytest.skip("dcsms console script not installed (run `make venv`)")
    env = dict(os.environ)
    env.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
    proc = subprocess.run([str(exe), "model", "eig", "--ideal", "--json"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["stable"] is True
    assert doc["modes"][0]["eigenvalue_hz"][1] == pytest.approx(EQ9[0][1], abs=5e-5)
    proc = subprocess.run([str(exe), "model", "eig", "--set", "m1=-1"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1
