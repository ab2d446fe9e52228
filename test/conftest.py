"""Markers and fixtures shared by every test: a private ROS domain per test, private rclpy
contexts and the Table 1 preset.

Markers (``pytest -m unit`` runs in seconds without DDS; ``make test`` runs everything):

- ``ros``: starts ROS participants (uses the ``domain`` fixture, or lives in ``test/nodes`` or
  ``test/reliability``);
- ``reliability``: the fault-injection suite (``test/reliability``);
- ``slow``: takes more than a few seconds (a module's ``pytestmark``, or a test's mark);
- ``unit``: everything else. rclpy is imported only by the tests that use it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from rosdomains import lease_domains

from dcsms_ros.core.config import SystemConfig, load_config

if TYPE_CHECKING:
    from rclpy.context import Context

TABLE1 = Path(__file__).resolve().parents[1] / "config" / "table1.yaml"
ROS_DIRS = ("nodes", "reliability")
MARKERS = {
    "unit": "fast, no DDS (everything not marked ros or slow)",
    "ros": "starts ROS participants over real DDS in a private domain",
    "reliability": "fault injection into the running graph (test/reliability)",
    "slow": "takes more than a few seconds",
}


def pytest_configure(config: pytest.Config) -> None:
    for name, text in MARKERS.items():
        config.addinivalue_line("markers", f"{name}: {text}")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test ``ros`` / ``reliability`` by where it lives and what it uses, and
    ``unit`` when it is neither ROS nor slow."""
    here = Path(__file__).resolve().parent
    for item in items:
        parts = Path(str(item.path)).resolve().relative_to(here).parts
        if parts[0] == "reliability":
            item.add_marker(pytest.mark.reliability)
        if parts[0] in ROS_DIRS or "domain" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.ros)
        if item.get_closest_marker("ros") is None and item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.unit)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Why each rerun attempt failed (pytest-rerunfailures lists only its name): a test that
    passed on a rerun still leaves its first failure in the CI log."""
    for rep in terminalreporter.stats.get("rerun", []):
        crash = getattr(rep.longrepr, "reprcrash", None)
        why = crash.message if crash is not None else str(rep.longrepr)
        first = why.strip().splitlines()[:3]
        terminalreporter.write_line(f"RERUN REASON {rep.nodeid}: {' | '.join(first)[:600]}")


def pytest_addoption(parser: pytest.Parser) -> None:
    """``--soak``: run the reliability soak for its full duration (10 minutes)."""
    parser.addoption("--soak", action="store_true", default=False,
                     help="run test/reliability/test_soak.py for 10 minutes (default: 25 s)")


@pytest.fixture
def domain(monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """This test's own ROS_DOMAIN_ID (also exported to child processes), localhost only."""
    lease = lease_domains()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(lease.first))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    yield lease.first
    lease.release()


@pytest.fixture
def ctx(domain: int) -> Iterator[Context]:
    """An initialised private rclpy context in this test's domain."""
    import rclpy
    from rclpy.context import Context

    c = Context()
    rclpy.init(args=[], context=c, domain_id=domain)
    yield c
    rclpy.try_shutdown(context=c)


@pytest.fixture
def gil_holder() -> Iterator[Callable[[float], list[float]]]:
    """``hold(after_s)``: a thread that, ``after_s`` s from now, holds the GIL for 50-150 ms in
    one C call (``sum`` over a range checks for no switch request); returns the list that
    gets its start and end (monotonic s) and the CPU time it used (s), all three once it
    ended. Every holder is joined at the end of the test."""
    threads: list[threading.Thread] = []

    def hold(after_s: float) -> list[float]:
        span: list[float] = []

        def run() -> None:
            time.sleep(after_s)
            t0, c0 = time.monotonic(), time.thread_time()
            sum(range(15_000_000))
            span.extend([t0, time.monotonic(), time.thread_time() - c0])

        threads.append(threading.Thread(target=run, name="gil-holder"))
        threads[-1].start()
        return span

    yield hold
    for t in threads:
        t.join()


#: The child of :func:`process_pause`: stops the process ``argv[1]`` after ``argv[2]`` s for
#: ``argv[3]`` s, continues it whatever happens, prints the pause's start and end (monotonic s).
_PAUSER = """
import os, signal, sys, time
pid, after, span = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
print("ready", flush=True)
time.sleep(after)
t0 = time.monotonic()
os.kill(pid, signal.SIGSTOP)
try:
    time.sleep(span)
finally:
    t1 = time.monotonic()
    os.kill(pid, signal.SIGCONT)
print(t0, t1)
"""


@pytest.fixture
def process_pause() -> Iterator[Callable[[float, float], Callable[[], tuple[float, float]]]]:
    """``pause(after_s, for_s)``: ``after_s`` s after it returns another process stops this
    whole process (SIGSTOP) for ``for_s`` s, as a paused virtual machine would: no thread of
    it runs. Returns ``span()``, which waits for the pause to end and gives its start and end
    (monotonic s)."""
    kids: list[subprocess.Popen[str]] = []

    def pause(after_s: float, for_s: float) -> Callable[[], tuple[float, float]]:
        kid = subprocess.Popen([sys.executable, "-c", _PAUSER, str(os.getpid()), str(after_s),
                                str(for_s)], stdout=subprocess.PIPE, text=True)
        kids.append(kid)
        assert kid.stdout is not None and kid.stdout.readline() == "ready\n"

        def span() -> tuple[float, float]:
            t0, t1 = (float(x) for x in kid.communicate(timeout=10)[0].split())
            return t0, t1

        return span

    yield pause
    for kid in kids:
        kid.wait(10)


@pytest.fixture
def cfg() -> SystemConfig:
    """The paper's Table 1 preset."""
    return load_config(TABLE1)
