"""``dcsms up``: arguments refused with one line and exit 2 before any node starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcsms_ros.cli import main

UNSTABLE = Path(__file__).resolve().parents[1] / "fixtures" / "tem_unstable.yaml"


@pytest.mark.parametrize("extra, message", [
    (["--rt-priority", "120"], "--rt-priority 120: must be 0 (off) or 1..99"),
    (["--rt-priority", "-1"], "--rt-priority -1"),
    (["--duration", "0"], "must be > 0"),
    (["--mode", "warp"], "unknown mode"),
])
def test_bad_arguments_are_one_line_exit_2(extra: list[str], message: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Out-of-range priority, duration, an unknown mode: one line on stderr, exit 2."""
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
