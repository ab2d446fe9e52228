"""``dcsms up``: arguments refused with one line and exit 2 before any node starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcsms_ros.cli import main
from dcsms_ros.cli.common import start_refusal
from dcsms_ros.core.config import load_config, parse_override
from dcsms_ros.core.modes import Mode

UNSTABLE = Path(__file__).resolve().parents[1] / "fixtures" / "tem_unstable.yaml"
TABLE1 = Path(__file__).resolve().parents[2] / "config" / "table1.yaml"


@pytest.mark.parametrize("extra, message", [
    (["--rt-priority", "120"], "--rt-priority 120: must be 0 (off) or 1..99"),
    (["--rt-priority", "-1"], "--rt-priority -1"),
    (["--rt-cpus", "a-b"], "--rt-cpus 'a-b': not a CPU list such as 1 or 0,2-3"),
    (["--rt-cpus", "4096"], "--rt-cpus 4096: this process may use CPUs"),
    (["--duration", "0"], "must be > 0"),
    (["--mode", "warp"], "unknown mode"),
])
def test_bad_arguments_are_one_line_exit_2(extra: list[str], message: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Out-of-range priority, a bad or unavailable CPU list, duration, an unknown mode: one
    line on stderr, exit 2."""
    assert main(["up", "--lockstep", *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dcsms: error:") and message in err, err


@pytest.mark.parametrize("command", [["up", "--lockstep"],
                                     ["sim", "--engine", "graph", "--duration", "1"]])
def test_an_unstable_initial_mode_is_refused(command: list[str], tmp_path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """The initial mode passes the guard a switch passes: DFBC on the unstable fixture is
    refused with the model's pole in one line, exit 2, nothing started or written."""
    out = tmp_path / "bag"
    extra = ["--out", str(out)] if command[0] == "sim" else []
    assert main([*command, "--mode", "DFBC", "--config", str(UNSTABLE), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dcsms: error: --mode DFBC: DFBC is "
                                                   "unstable"), err
    assert "+0.0576 +0.4249j Hz" in err and "--allow-unstable" in err
    assert not out.exists()


def test_a_real_time_start_that_late_forces_destabilise_is_refused(
        tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    """Real time applies a force up to control.input_timeout_s late: table1's DFBC tolerates
    16.5 ms with both feedback controllers late, so a 20 ms timeout is refused at start (one
    line naming the margin, exit 2, nothing recorded); 10 ms (the preset) is not."""
    out = tmp_path / "bag"
    assert main(["up", "--realtime", "--mode", "DFBC", "--config", str(TABLE1), "--set",
                 "control.input_timeout_s=0.02", "--record", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(
        "dcsms: error: --mode DFBC: DFBC goes unstable with forces 20 ms late"), err
    assert "delay margin of all is 16.5 ms" in err and "--allow-unstable" in err
    assert not out.exists()


def test_the_start_verdict_is_computed_once_per_configuration(
        tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The refusal's verdict is cached like the model check (importing the loop model costs
    1.1-1.5 s of every start): the first call computes and keeps it, a second reads it back (a
    verdict planted in the file is what it returns), and another timeout, mode or schedule is
    another entry, computed afresh."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    late = load_config(TABLE1, dict([parse_override("control.input_timeout_s=0.02")]))
    first = start_refusal(late, Mode.DFBC, realtime=True)
    assert first is not None and first.startswith("DFBC goes unstable with forces 20 ms late")
    files = list((tmp_path / "dcsms").glob("check-*.json"))
    assert len(files) == 1
    files[0].write_text('["planted"]')
    assert start_refusal(late, Mode.DFBC, realtime=True) == "planted"
    assert start_refusal(late, Mode.DFBC, realtime=False) is None  # lockstep: no late forces
    assert start_refusal(load_config(TABLE1), Mode.DFBC, realtime=True) is None
    start_refusal(late, Mode.FBC, realtime=True)
    assert len(list((tmp_path / "dcsms").glob("check-*.json"))) == 4
