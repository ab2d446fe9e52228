"""The bounded teardown of a node process (``RosSession.bound_teardown``, ros/context.py): a
destruction that hangs with the GIL held ends after the bound; a quick one leaves no timer."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dcsms_ros.cli import processes

#: A node process whose node's destruction blocks in C holding the GIL for 60 s (as rclpy's
#: teardown of a node did in the middleware, docs/performance.md): its attachment is finished
#: first, then the bounded teardown (patched to 1 s) ends it. With ``quick``: a node whose
#: destruction is quick, and the process lives on for 2 s after its context is shut down.
#: With ``stopped``: it hangs too, with the package's bound, and waits for a SIGINT.
HUNG_TEARDOWN = r"""
import ctypes, os, signal, sys, time
from rclpy.node import Node
from dcsms_ros.ros import context
from dcsms_ros.ros.runtime import run

hang = sys.argv[1] in ("hang", "stopped")
if sys.argv[1] != "stopped":
    context.TEARDOWN_BOUND_S = 1.0

class Node_(Node):
    def __init__(self, context):
        super().__init__("hung_teardown", context=context)
        if sys.argv[1] == "stopped":
            print("up", flush=True)
        else:
            self.create_timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))

    def destroy_node(self):
        print("destroy", flush=True)
        if hang:
            ctypes.PyDLL(None).sleep(60)  # libc's sleep, the GIL held
        super().destroy_node()

class Part:
    def finish(self):
        print("finish", flush=True)

    def abort(self):
        print("abort", flush=True)

status = run(Node_, ["x"], lambda node: Part())
time.sleep(2.0)
print("alive", flush=True)
sys.exit(status)
"""


def test_a_teardown_that_hangs_with_the_gil_held_ends_after_its_bound(
        domain: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The node's part is finished, its destruction blocks holding the GIL (deaf to signals);
    faulthandler's timer ends the process 1 s later with status 1 and the threads' stacks in
    its log, and ``dcsms up`` says so in one line."""
    kid = processes.Child("hung", [sys.executable, "-c", HUNG_TEARDOWN, "hang"])
    t0 = time.monotonic()
    processes.start([kid], tmp_path, verbose=False)
    assert kid.proc is not None
    assert kid.proc.wait(timeout=50) == 1
    assert time.monotonic() - t0 < 30.0  # not the 60 s of the hang
    text = (tmp_path / "hung.log").read_text()
    assert text.split("\n")[:2] == ["finish", "destroy"], text
    assert "Timeout (0:00:01)!" in text and "in destroy_node" in text, text
    assert "alive" not in text
    assert processes.report_exits([kid]) == 1
    assert capsys.readouterr().err.strip() == (
        f"dcsms up: hung saved everything but its teardown did not end in time, so it ended "
        f"itself (its threads' stacks are in its log: {tmp_path / 'hung.log'})")


def test_the_teardown_bound_ends_with_the_context(domain: int) -> None:
    """A quick teardown: the bound is cancelled when the context is shut down, so the process
    lives on past it and exits 0."""
    out = subprocess.run([sys.executable, "-c", HUNG_TEARDOWN, "quick"], capture_output=True,
                         text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["finish", "destroy", "alive"]
    assert "Timeout" not in out.stderr


def test_a_hung_teardown_ends_itself_before_dcsms_up_would_abort_it(
        domain: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """With the package's bound, a node that hangs in its teardown after ``dcsms up``'s SIGINT
    ends itself within the SIGINT's timeout: it is reported as a teardown that did not end, not
    as a process that did not stop (which says its data may be lost). A CI run of the lanes
    test had mode_switch aborted 7 s after the SIGINT while the bound was 10 s."""
    kid = processes.Child("hung", [sys.executable, "-c", HUNG_TEARDOWN, "stopped"])
    processes.start([kid], tmp_path, verbose=False)
    assert kid.proc is not None
    log = tmp_path / "hung.log"
    deadline = time.monotonic() + 30.0
    while "up" not in log.read_text().split() and time.monotonic() < deadline:
        time.sleep(0.05)
    t0 = time.monotonic()
    processes.stop([kid])
    took = time.monotonic() - t0
    assert kid.stopped_by is signal.SIGINT, (took, log.read_text())
    assert kid.proc.returncode == 1
    assert took < processes.STOP_TIMEOUTS[0]
    assert processes.report_exits([kid]) == 1
    assert "saved everything but its teardown did not end" in capsys.readouterr().err
