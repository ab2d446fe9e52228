"""Issue 21 item 5: the initial mode passes the same stability guard as a switch. With the
configuration the model calls DFBC-unstable (``tem_unstable.yaml``), ``dcsms up --mode DFBC``
and the ``mode_switch`` executable with ``initial_mode:=DFBC`` refuse with one line and exit
2 (real processes, real exit codes); ``allow_unstable`` lets the node start."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import yaml

from dcsms_ros.core.check import unstable_reason
from dcsms_ros.core.config import load_config
from dcsms_ros.core.modes import Mode

REPO = Path(__file__).resolve().parents[2]
UNSTABLE = REPO / "test" / "fixtures" / "tem_unstable.yaml"
NODE = [sys.executable, "-m", "dcsms_ros.nodes.mode_switch"]


def _params_file(tmp: Path) -> Path:
    """The fixture's configuration as a ROS 2 params file (empty lists left out: ROS cannot
    type them, the node's defaults are the same)."""
    flat = {k: v for k, v in (load_config(UNSTABLE).params or {}).items()
            if not (isinstance(v, list) and not v)}
    path = tmp / "params.yaml"
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": flat}}))
    return path


def _one_error_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    return lines[0]


def test_fixture_is_dfbc_unstable() -> None:
    """The premise, judged independently of the refusal: the model calls DFBC unstable."""
    cfg = load_config(UNSTABLE)
    assert unstable_reason(cfg, Mode.DFBC) is not None
    assert unstable_reason(cfg, Mode.PASSIVE) is None


def test_up_refuses_an_unstable_initial_mode(domain: int, tmp_path: Path) -> None:
    """`dcsms up --mode DFBC` exits 2 with one `dcsms: error:` line naming the pole, before
    any process starts (no log directory is made)."""
    logs = tmp_path / "logs"
    proc = subprocess.run([sys.executable, "-m", "dcsms_ros.cli", "up", "--lockstep",
                           "--composed", "--mode", "DFBC", "--config", str(UNSTABLE),
                           "--duration", "0.5", "--log-dir", str(logs)],
                          capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    line = _one_error_line(proc.stderr)
    assert line.startswith("dcsms: error: --mode DFBC: DFBC is unstable"), line
    assert "pole at" in line and "--allow-unstable" in line, line
    assert not logs.exists()


def test_mode_switch_node_refuses_an_unstable_initial_mode(domain: int, tmp_path: Path) -> None:
    """The executable with ``initial_mode:=DFBC`` exits 2 with one line; with
    ``allow_unstable:=true`` it runs until SIGINT and exits 0."""
    params = _params_file(tmp_path)
    argv = [*NODE, "--ros-args", "--params-file", str(params), "-p", "initial_mode:=DFBC"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    line = _one_error_line(proc.stderr)
    assert line.startswith("dcsms: error: node mode_switch: initial_mode DFBC: DFBC is "
                           "unstable"), line
    assert "refused (allow_unstable is false)" in line, line

    out = tmp_path / "allowed.log"
    with out.open("w") as f:
        run = subprocess.Popen([*argv, "-p", "allow_unstable:=true"], stdout=f,
                               stderr=subprocess.STDOUT)
    try:
        end = time.monotonic() + 120.0  # the warning comes from construction: past it
        while "allowed (allow_unstable)" not in out.read_text() and time.monotonic() < end:
            assert run.poll() is None, out.read_text()
            time.sleep(0.2)
        time.sleep(1.0)
        assert run.poll() is None, out.read_text()
        run.send_signal(signal.SIGINT)
        assert run.wait(60) == 0, out.read_text()
    finally:
        if run.poll() is None:
            run.kill()
    assert "allowed (allow_unstable)" in out.read_text()
