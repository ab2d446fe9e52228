"""The processes ``dcsms up`` starts: their environment, start, stop and the report of how they
ended.

Every child runs in a session of its own (the terminal's Ctrl-C reaches only the parent, which
stops them in order), so nothing the terminal does reaches it; if the parent dies without
stopping them (SIGKILL, or a caller such as ``make bench`` interrupted, whose ``subprocess.run``
kills it), the kernel sends each child SIGTERM (Linux ``PR_SET_PDEATHSIG``), its ordinary clean
stop: no process is left behind, and a recorder still closes its bag. A stop is SIGINT, then
SIGTERM, SIGABRT (a stuck process writes its threads' stacks into its log) and SIGKILL after
timeouts.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Collection, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dcsms_ros.rosenv import keep_discovery_local

#: Seconds a process gets to exit after SIGINT, then after SIGTERM, before SIGKILL.
STOP_TIMEOUTS = (5.0, 2.0)
#: The same for the recorder, which writes its whole backlog first (recorder.DRAIN_MAX_S).
RECORDER_STOP_TIMEOUTS = (40.0, 5.0)
#: Seconds a child still running after both gets to write its threads' stacks (SIGABRT).
ABORT_TIMEOUT_S = 2.0
#: Seconds a process left behind by a dead child gets to end before SIGKILL (a bag writer
#: closing a bag: bagprocess.CLOSE_TIMEOUT_S).
ORPHAN_TIMEOUT_S = 120.0


@dataclass
class Child:
    """One process."""

    name: str
    argv: list[str]
    log: Path | None = None
    proc: subprocess.Popen[bytes] | None = None
    env: dict[str, str] = field(default_factory=dict)
    #: added to the process's niceness (0: the parent's)
    nice: int = 0
    #: the last signal :func:`stop` sent it
    stopped_by: signal.Signals | None = None


def child_env() -> dict[str, str]:
    """Environment of the processes: localhost discovery, unbuffered, plain logs, and a
    Python traceback in the log if one crashes in native code (a process that died of a
    signal otherwise leaves nothing there: :func:`report_exits` names the signal)."""
    env = dict(os.environ)
    keep_discovery_local(env)
    env["PYTHONUNBUFFERED"] = "1"
    env.setdefault("PYTHONFAULTHANDLER", "1")
    env.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    return env


#: ``prctl`` options (linux/prctl.h): the signal a process gets when its parent dies; a
#: process that adopts its descendants' orphans, and the query of it.
PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36
PR_GET_CHILD_SUBREAPER = 37


@dataclass(frozen=True)
class Orphan:
    """A process a dead child left behind, after :func:`reap_orphans` waited for it."""

    pid: int
    #: the module it ran (``python -m``) or its program's name
    name: str
    #: its exit status (negative: the signal that ended it)
    code: int
    #: True if it did not end within the timeout and was killed
    killed: bool = False


def _dies_with(parent: int, nice: int = 0) -> Callable[[], None] | None:
    """A ``preexec_fn`` that makes the child get SIGTERM when process ``parent`` (the caller
    of :func:`start`, from its calling thread) dies, and adds ``nice`` to its niceness; None
    where ``prctl`` does not exist."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up before the fork

    def arm() -> None:
        prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM))
        if os.getppid() != parent:  # it died before the line above
            os.kill(os.getpid(), signal.SIGTERM)
        if nice:
            os.nice(nice)

    return arm


@contextmanager
def adopting_orphans() -> Iterator[bool]:
    """While it holds, a process left behind by a dead descendant becomes this process's
    child (:func:`reap_orphans` waits for it) instead of init's. Yields False where that is
    not possible (not Linux); the previous setting is restored at the end."""
    if not sys.platform.startswith("linux"):
        yield False
        return
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    before = ctypes.c_int(0)
    prctl(PR_GET_CHILD_SUBREAPER, ctypes.byref(before))
    ok = prctl(PR_SET_CHILD_SUBREAPER, 1) == 0
    try:
        yield ok
    finally:
        prctl(PR_SET_CHILD_SUBREAPER, before.value)


def _session(pid: int) -> int | None:
    """The session of process ``pid`` (None if it is gone)."""
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[3])
    except (OSError, IndexError, ValueError):
        return None


def _children() -> set[int]:
    """The pids of this process's children (every thread's)."""
    pids: set[int] = set()
    for path in Path(f"/proc/{os.getpid()}/task").glob("*/children"):
        try:
            pids.update(int(p) for p in path.read_text().split())
        except OSError:  # the thread ended
            continue
    return pids


def _program(pid: int) -> str:
    """The module ``pid`` runs (``python -m``) or its program's name; once it has exited (a
    zombie has no command line) the name it gave itself (``comm``; the bag writer's is
    ``bagserve``)."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
        if "-m" in argv[:-1]:
            return argv[argv.index("-m") + 1]
        return Path(argv[0]).name or Path(f"/proc/{pid}/comm").read_text().strip() or "?"
    except OSError:
        return "?"


def reap_orphans(kids: Collection[Child], timeout: float = ORPHAN_TIMEOUT_S) -> list[Orphan]:
    """Wait for every process that one of ``kids`` left behind (adopted while
    :func:`adopting_orphans` held; it is in the session of the child that started it, which
    :func:`start` made its own), SIGKILL after ``timeout`` seconds in all. Call it once
    ``kids`` exited; other children of this process are left alone."""
    known = {k.proc.pid for k in kids if k.proc is not None}
    pending: dict[int, str] = {}
    done: list[Orphan] = []
    t0 = time.monotonic()
    said = False
    while True:
        # again each time: one that ends may leave its own behind, in the same session
        for pid in _children() - known - pending.keys():
            if _session(pid) in known:
                pending[pid] = _program(pid)
        for pid in list(pending):
            got, status = os.waitpid(pid, os.WNOHANG)
            if got:
                done.append(Orphan(pid, pending.pop(pid), os.waitstatus_to_exitcode(status)))
        if not pending:
            return done
        waited = time.monotonic() - t0
        if waited >= timeout:
            for pid, name in pending.items():
                os.kill(pid, signal.SIGKILL)
                done.append(Orphan(pid, name, os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]),
                                   killed=True))
            return done
        if waited >= 1.0 and not said:
            print(f"dcsms up: waiting up to {timeout:.0f} s for "
                  f"{', '.join(f'{n} (pid {p})' for p, n in pending.items())}, left behind by a "
                  "process that died", file=sys.stderr, flush=True)
            said = True
        time.sleep(0.05)


def start(kids: Sequence[Child], log_dir: Path, verbose: bool) -> None:
    """Start every child in its own session (the terminal's Ctrl-C reaches only ``up``); each
    gets SIGTERM if this process dies without stopping it (see the module notes)."""
    env = child_env()
    parent = os.getpid()
    for kid in kids:
        out: Any = None
        if not verbose:
            kid.log = log_dir / f"{kid.name}.log"
            out = kid.log.open("wb")
        # the preexec only makes one system call (prctl), safe in a forked child of a process
        # with threads; the graph is started before `up` creates its rclpy context anyway
        kid.proc = subprocess.Popen(kid.argv, stdout=out, stderr=subprocess.STDOUT if out else
                                    None, stdin=subprocess.DEVNULL, env={**env, **kid.env},
                                    start_new_session=True,
                                    preexec_fn=_dies_with(parent, kid.nice))  # noqa: PLW1509
        if out is not None:
            out.close()


def stop(kids: Sequence[Child], timeouts: tuple[float, float] = STOP_TIMEOUTS) -> None:
    """SIGINT to every running child, then SIGTERM, then SIGABRT, then SIGKILL after the
    timeouts. SIGABRT makes a stuck child's fault handler (``PYTHONFAULTHANDLER``, set by
    :func:`child_env`) write every thread's stack into its log, so a hang can be told apart."""
    for sig, timeout in ((signal.SIGINT, timeouts[0]), (signal.SIGTERM, timeouts[1]),
                         (signal.SIGABRT, ABORT_TIMEOUT_S), (signal.SIGKILL, 5.0)):
        alive = [k for k in kids if k.proc is not None and k.proc.poll() is None]
        if not alive:
            return
        for k in alive:
            k.stopped_by = sig
            try:
                k.proc.send_signal(sig)  # type: ignore[union-attr]
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + timeout
        for k in alive:
            try:
                k.proc.wait(max(deadline - time.monotonic(), 0.0))  # type: ignore[union-attr]
            except subprocess.TimeoutExpired:
                pass


def stop_in_turn(kids: Sequence[Child], timeouts: tuple[float, float] = STOP_TIMEOUTS) -> None:
    """:func:`stop` each of ``kids`` after the one before it exited, in reverse start order (the
    plant, the source of every sample, first; mode_switch last).

    Stopped together, the processes delete their DDS participants while each one's receive
    threads handle the others' endpoints going away, and Fast DDS 2.14 (Jazzy) can then hang a
    deletion for good: rmw's ``destroy_participant`` calls ``DomainParticipant::set_listener``,
    which spins (its wait until ``system_clock``'s maximum never sleeps) while a discovery
    callback is running, and takes the participant's mutex back so fast that the callback never
    gets it to finish (gdb of a hung ff_stage1, docs/performance.md, thirty-seventh session).
    One at a time, a process tears down while the others are idle."""
    for kid in reversed(kids):
        stop([kid], timeouts)


def report_exits(kids: Sequence[Child], orphans: Sequence[Orphan] = ()) -> int:
    """One line on stderr for each stopped process that did not exit cleanly (a node that
    failed while closing, or one killed after the stop timeouts: what it held back, its part
    of the bag included, may be lost), and one for each process a dead one left behind
    (:func:`reap_orphans`); 1 if there was one, else 0."""
    status = 0
    for kid in kids:
        code = kid.proc.returncode if kid.proc is not None else None
        if code in (0, None):
            continue
        how = _ended(code)
        log = f"its log: {kid.log}"
        if code == -signal.SIGABRT and kid.stopped_by is signal.SIGABRT:
            how, log = "did not stop and was aborted", f"its threads' stacks are in {log}"
        elif code == 1 and kid.log is not None and _teardown_timed_out(kid.log):
            how = "saved everything but its teardown did not end in time, so it ended itself"
            log = f"its threads' stacks are in {log}"
        print(f"dcsms up: {kid.name} {how}" + (f" ({log})" if kid.log else ""),
              file=sys.stderr, flush=True)
        status = 1
    for o in orphans:
        print(f"dcsms up: {o.name} (pid {o.pid}), left behind by a process that died, "
              f"{'did not end in time and was killed' if o.killed else _ended(o.code)}",
              file=sys.stderr, flush=True)
        status = 1
    return status


def _ended(code: int) -> str:
    """How a process with exit status ``code`` ended, for a line of :func:`report_exits`."""
    return (f"was killed by {signal.Signals(-code).name}" if code < 0 and
            -code in signal.valid_signals() else f"exited with status {code}")


def _teardown_timed_out(log: Path) -> bool:
    """True if ``log`` ends with the stacks a node's bounded teardown writes when it runs
    out (:meth:`dcsms_ros.ros.context.RosSession.bound_teardown`: faulthandler's
    ``Timeout (h:mm:ss)!`` line, then the threads)."""
    try:
        with log.open("rb") as f:
            f.seek(max(f.seek(0, os.SEEK_END) - 65536, 0))
            tail = f.read().decode(errors="replace")
    except OSError:
        return False
    return any(line.startswith("Timeout (") and line.rstrip().endswith(")!")
               for line in tail.splitlines())


__all__ = ["ABORT_TIMEOUT_S", "ORPHAN_TIMEOUT_S", "RECORDER_STOP_TIMEOUTS", "STOP_TIMEOUTS",
           "Child", "Orphan", "adopting_orphans", "child_env", "reap_orphans", "report_exits",
           "start", "stop", "stop_in_turn"]
