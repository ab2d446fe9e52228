"""The processes a deployment starts (cli/processes.py): no child outlives its parent (a parent
killed with SIGKILL, as `make bench` interrupted kills `dcsms up`, leaves no process behind, and
the recorder it started still closes its bag: SIGTERM is its clean stop), how each one ended is
reported, a stuck one is aborted with its stacks, and the graph stops one process at a time."""

from __future__ import annotations

import ctypes
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dcsms_ros.cli import processes

pytestmark = [pytest.mark.ros, pytest.mark.slow]

#: The parent: starts a recorder and an idle child through processes.start, prints their pids,
#: then waits to be killed.
PARENT = r"""
import json, sys, time
from pathlib import Path
from dcsms_ros.cli import deploy, processes
out = Path(sys.argv[1])
kids = [processes.Child("recorder", deploy.recorder_command(out / "bag", ["/reap/*"])),
        processes.Child("idle", [sys.executable, "-c", "import time; time.sleep(120)"])]
processes.start(kids, out, verbose=False)
print(json.dumps([k.proc.pid for k in kids]), flush=True)
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux")
def test_children_end_when_the_parent_is_killed(domain: int, tmp_path: Path) -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT, str(tmp_path)],
                              stdout=subprocess.PIPE, text=True, start_new_session=True)
    kids: list[int] = []
    try:
        assert parent.stdout is not None
        kids = json.loads(parent.stdout.readline())
        assert len(kids) == 2 and all(_alive(p) for p in kids)
        # the recorder is up (it logs its start) before its parent goes
        log = tmp_path / "recorder.log"
        end = time.monotonic() + 30.0
        while "recording" not in (log.read_text() if log.exists() else "") and \
                "0 messages" not in (log.read_text() if log.exists() else "") and \
                time.monotonic() < end:
            time.sleep(0.1)
        time.sleep(1.0)
        parent.send_signal(signal.SIGKILL)
        parent.wait(10.0)
        end = time.monotonic() + 20.0
        while any(_alive(p) for p in kids) and time.monotonic() < end:
            time.sleep(0.05)
        assert not any(_alive(p) for p in kids), [p for p in kids if _alive(p)]
        # the recorder stopped cleanly: its bag is closed, not left half-written
        assert (tmp_path / "bag" / "metadata.yaml").exists(), log.read_text()[-2000:]
        assert not (tmp_path / "bag.partial").exists()
    finally:
        for pid in [parent.pid, *kids]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("nice", [0, 10])
def test_a_child_runs_at_the_niceness_it_asks(nice: int, tmp_path: Path) -> None:
    """`Child.nice` adds to the child's niceness (a real-time run's recorder: +10), and only
    to that child."""
    probe = [sys.executable, "-c", "import os; print(os.nice(0))"]
    kids = [processes.Child("asked", probe, nice=nice), processes.Child("plain", probe)]
    processes.start(kids, tmp_path, verbose=False)
    for k in kids:
        assert k.proc is not None and k.proc.wait(30) == 0
    base = os.nice(0)
    assert int((tmp_path / "asked.log").read_text()) == min(base + nice, 19)
    assert int((tmp_path / "plain.log").read_text()) == base


#: A process that dies of SIGSEGV in native code, called from a Python function ``native``.
CRASH = "import ctypes\ndef native(): ctypes.string_at(0)\nnative()"


def test_every_process_that_did_not_exit_cleanly_is_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """After the stop, a process that failed while closing, crashed or was killed gets one
    line each and the run's status 1; clean exits say nothing. A native crash leaves a Python
    traceback in the process's log."""
    kids = [processes.Child("clean", [sys.executable, "-c", "pass"]),
            processes.Child("failed", [sys.executable, "-c", "raise SystemExit(3)"]),
            processes.Child("killed", [sys.executable, "-c", "import time; time.sleep(60)"]),
            processes.Child("crashed", [sys.executable, "-c", CRASH])]
    processes.start(kids, tmp_path, verbose=False)
    assert kids[2].proc is not None
    kids[2].proc.kill()
    for k in kids:
        assert k.proc is not None
        k.proc.wait(30.0)
    assert processes.report_exits(kids) == 1
    err = capsys.readouterr().err.splitlines()
    logs = {k.name: tmp_path / f"{k.name}.log" for k in kids}
    assert err == [f"dcsms up: failed exited with status 3 (its log: {logs['failed']})",
                   f"dcsms up: killed was killed by SIGKILL (its log: {logs['killed']})",
                   f"dcsms up: crashed was killed by SIGSEGV (its log: {logs['crashed']})"]
    crash = logs["crashed"].read_text()
    assert "Segmentation fault" in crash and "in native" in crash, crash
    assert processes.report_exits(kids[:1]) == 0
    assert capsys.readouterr().err == ""


#: A process that ignores SIGINT and SIGTERM and blocks in a Python function ``stuck``.
STUCK = ("import signal, time\n"
         "for s in (signal.SIGINT, signal.SIGTERM): signal.signal(s, signal.SIG_IGN)\n"
         "def stuck(): time.sleep(60)\n"
         "print('ready', flush=True)\nstuck()")


def test_a_child_that_does_not_stop_leaves_its_stacks_in_its_log(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A child that ignores SIGINT and SIGTERM is aborted before it is killed: its fault
    handler writes where each of its threads waited into its log, and the report says so."""
    kid = processes.Child("stuck", [sys.executable, "-c", STUCK])
    processes.start([kid], tmp_path, verbose=False)
    log = tmp_path / "stuck.log"
    end = time.monotonic() + 30.0
    while "ready" not in log.read_text() and time.monotonic() < end:
        time.sleep(0.05)
    t0 = time.monotonic()
    processes.stop([kid], (0.5, 0.5))
    assert kid.proc is not None and kid.proc.returncode == -signal.SIGABRT
    assert time.monotonic() - t0 < 0.5 + 0.5 + processes.ABORT_TIMEOUT_S + 1.0
    text = log.read_text()
    assert "Fatal Python error: Aborted" in text and "in stuck" in text, text
    assert processes.report_exits([kid]) == 1
    assert capsys.readouterr().err.strip() == (
        f"dcsms up: stuck did not stop and was aborted (its threads' stacks are in its log: "
        f"{log})")


#: A child that, on SIGINT, notes when it started stopping, takes 0.3 s, notes when it ended.
SLOW_STOP = r"""
import signal, sys, time
def stop(*_):
    with open(sys.argv[1], "a") as f:
        f.write(f"{sys.argv[2]} begin {time.monotonic()}\n")
    time.sleep(0.3)
    with open(sys.argv[1], "a") as f:
        f.write(f"{sys.argv[2]} end {time.monotonic()}\n")
    sys.exit(0)
signal.signal(signal.SIGINT, stop)
print("up", flush=True)
time.sleep(60)
"""


def test_stop_in_turn_stops_each_child_after_the_one_started_after_it_exited(
        tmp_path: Path) -> None:
    """The graph stops one process at a time, in reverse start order: each begins its stop
    only after the one before it ended (a participant deleted while another process deletes
    its endpoints can hang in Fast DDS 2.14), and each exits cleanly."""
    notes = tmp_path / "notes"
    kids = [processes.Child(n, [sys.executable, "-c", SLOW_STOP, str(notes), n])
            for n in ("first", "second", "third")]
    processes.start(kids, tmp_path, verbose=False)
    deadline = time.monotonic() + 30.0
    while not all((tmp_path / f"{k.name}.log").read_text().strip() == "up" for k in kids):
        assert time.monotonic() < deadline, "the children did not start"
        time.sleep(0.05)
    processes.stop_in_turn(kids)
    rows = [line.split() for line in notes.read_text().splitlines()]
    assert [(r[0], r[1]) for r in rows] == [
        ("third", "begin"), ("third", "end"), ("second", "begin"), ("second", "end"),
        ("first", "begin"), ("first", "end")]
    times = [float(r[2]) for r in rows]
    assert times == sorted(times)
    assert all(k.proc is not None and k.proc.returncode == 0 for k in kids)
    assert processes.report_exits(kids) == 0


#: A child that starts a process of its own and exits at once, leaving it behind; that process
#: writes ``closed`` to argv[1] after argv[2] seconds and exits with status 3 (a composed
#: process's bag writer closing the bag once its parent died).
LEAVES_ONE = r"""
import subprocess, sys
subprocess.Popen([sys.executable, "-c",
                  "import sys, time; time.sleep(float(sys.argv[2])); "
                  "open(sys.argv[1], 'w').write('closed'); sys.exit(3)", *sys.argv[1:]])
"""


def _prctl_subreaper() -> int:
    flag = ctypes.c_int(-1)
    ctypes.CDLL(None).prctl(processes.PR_GET_CHILD_SUBREAPER, ctypes.byref(flag))
    return flag.value


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_CHILD_SUBREAPER")
def test_a_process_a_dead_child_left_behind_is_waited_for(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A child that died leaving a process of its own behind: the parent adopts it and waits
    for it, so what it does at its end (a bag closed) is done when the parent reports; one
    line says it waits (after 1 s), one how it ended. A child of the parent that no child
    started is left alone, and the parent's setting is restored after."""
    done = tmp_path / "done"
    kid = processes.Child("leaver", [sys.executable, "-c", LEAVES_ONE, str(done), "2.0"])
    own = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        before = _prctl_subreaper()
        with processes.adopting_orphans() as adopting:
            assert adopting and _prctl_subreaper() == 1
            processes.start([kid], tmp_path, verbose=False)
            assert kid.proc is not None and kid.proc.wait(30.0) == 0
            assert not done.exists()
            left = processes.reap_orphans([kid])
        assert _prctl_subreaper() == before
        assert done.read_text() == "closed"
        assert [(o.code, o.killed) for o in left] == [(3, False)]
        assert own.poll() is None
    finally:
        own.kill()
        own.wait()
    assert processes.report_exits([kid], left) == 1
    who = f"{left[0].name} (pid {left[0].pid}), left behind by a process that died"
    assert capsys.readouterr().err.splitlines() == [
        f"dcsms up: waiting up to {processes.ORPHAN_TIMEOUT_S:.0f} s for {who}",
        f"dcsms up: {who}, exited with status 3"]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_CHILD_SUBREAPER")
def test_a_process_left_behind_that_does_not_end_is_killed_after_the_timeout(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    done = tmp_path / "done"
    kid = processes.Child("leaver", [sys.executable, "-c", LEAVES_ONE, str(done), "60"])
    with processes.adopting_orphans():
        processes.start([kid], tmp_path, verbose=False)
        assert kid.proc is not None and kid.proc.wait(30.0) == 0
        t0 = time.monotonic()
        left = processes.reap_orphans([kid], timeout=0.5)
    assert time.monotonic() - t0 < 5.0
    assert [(o.code, o.killed) for o in left] == [(-signal.SIGKILL, True)]
    assert not done.exists()
    assert processes.report_exits([], left) == 1
    assert "did not end in time and was killed" in capsys.readouterr().err
