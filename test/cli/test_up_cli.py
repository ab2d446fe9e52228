"""``dcsms up``: arguments refused with one line and exit 2 before any node starts."""

from __future__ import annotations

import pytest

from dcsms_ros.cli import main


@pytest.mark.parametrize("extra, message", [
    (["--rt-priority", "120"], "--rt-priority 120: must be 0 (off) or 1..99"),
    (["--rt-priority", "-1"], "--rt-priority -1"),
    (["--duration", "0"], "must be > 0"),
    (["--mode", "warp"], "unknown mode"),
])
def test_bad_arguments_are_one_line_exit_2(extra: list[str], message: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Out-of-range priority, duration or an unknown mode: one line on stderr, exit 2."""
    assert main(["up", "--lockstep", *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("dcsms: error:") and message in err, err
