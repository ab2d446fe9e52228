"""``dcsms``'s entry point: what every sub-command's failure looks like to the user."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from dcsms_ros.cli import main, params


def test_a_file_the_system_refuses_is_one_line_and_exit_1(tmp_path: Path,
                                                         monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    """An OSError no sub-command foresaw (here a write below a regular file; in a run, a log
    directory removed while it ran) is the path and the reason on one line, exit 1."""
    (tmp_path / "file").write_text("keep me")
    target = tmp_path / "file" / "summary.json"

    def write(args: argparse.Namespace) -> int:
        target.write_text("{}")
        return 0

    monkeypatch.setattr(params, "run", write)
    assert main(["params"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("dcsms: error: [Errno 20] Not a directory") and str(target) in err[0]
    assert (tmp_path / "file").read_text() == "keep me"
