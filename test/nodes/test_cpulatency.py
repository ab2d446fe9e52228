"""The CPU wake-up latency a real-time hot loop holds (``ros/cpulatency.py``): read back from the
kernel's own PM QoS file, not from a stand-in."""

from __future__ import annotations

import contextlib
import os
import signal
import struct
import subprocess
import sys
import time

import pytest

from dcsms_ros.ros.cpulatency import (
    CPU_LATENCY_ENV,
    PM_QOS_PATH,
    CpuLatencyRequest,
    hold_from_env,
    latency_from_env,
)
from dcsms_ros.ros.runtime import RT_PRIORITY_ENV


def read_latency_us() -> int:
    """The wake-up latency (us) the kernel applies now: the smallest of all requests."""
    with open(PM_QOS_PATH, "rb") as f:
        return int(struct.unpack("i", f.read(4))[0])


def _writable() -> bool:
    return os.access(PM_QOS_PATH, os.W_OK)


def _has_fifo_thread(pid: int) -> bool:
    for tid in os.listdir(f"/proc/{pid}/task"):
        with contextlib.suppress(OSError):  # a thread that ended meanwhile
            if os.sched_getscheduler(int(tid)) == os.SCHED_FIFO:
                return True
    return False


needs_pm_qos = pytest.mark.skipif(not _writable(), reason=f"{PM_QOS_PATH} not writable here")


@pytest.mark.parametrize(("value", "expected"), [(None, 0), ("", 0), ("0", 0),
                                                  ("25", 25), ("off", None), ("OFF", None)])
def test_the_latency_comes_from_the_environment(monkeypatch, value, expected) -> None:
    """0 us unless the variable asks for another; ``off`` leaves the kernel's wake-up
    latency."""
    monkeypatch.delenv(CPU_LATENCY_ENV, raising=False)
    if value is not None:
        monkeypatch.setenv(CPU_LATENCY_ENV, value)
    assert latency_from_env() == (expected, None)


@pytest.mark.parametrize("value", ["-1", "abc", "1.5"])
def test_a_bad_value_is_a_warning_and_asks_for_nothing(monkeypatch, value) -> None:
    monkeypatch.setenv(CPU_LATENCY_ENV, value)
    for us, warning in (latency_from_env(), hold_from_env()):
        assert us is None and warning is not None and repr(value) in warning


def test_off_asks_for_nothing(monkeypatch) -> None:
    monkeypatch.setenv(CPU_LATENCY_ENV, "off")
    assert hold_from_env() == (None, None)


def test_a_refused_request_is_a_warning(tmp_path, monkeypatch) -> None:
    """A missing file (no PM QoS in this kernel) leaves the run going with one warning."""
    missing = tmp_path / "no_such_file"
    with pytest.raises(OSError):
        CpuLatencyRequest(0, missing)
    for value in ("0", None):  # asked for, or the default
        if value is None:
            monkeypatch.delenv(CPU_LATENCY_ENV, raising=False)
        else:
            monkeypatch.setenv(CPU_LATENCY_ENV, value)
        req, warning = hold_from_env(missing)
        assert req is None and warning is not None and "not held" in warning
        assert f"{CPU_LATENCY_ENV}=off" in warning


@needs_pm_qos
def test_a_request_holds_while_open_and_is_withdrawn_on_close() -> None:
    before = read_latency_us()
    assert before is not None
    req = CpuLatencyRequest(3)
    try:
        assert req.held and read_latency_us() == min(before, 3)
    finally:
        req.close()
    req.close()  # idempotent
    assert not req.held and read_latency_us() == before


@needs_pm_qos
@pytest.mark.parametrize(("value", "how"), [("0", signal.SIGINT), (None, signal.SIGKILL),
                                            ("off", signal.SIGINT)])
def test_a_real_time_node_holds_the_latency_it_was_given_while_it_runs(
        domain, value: str | None, how: int) -> None:
    """A control-path node under SCHED_FIFO holds 0 us while it runs (by default, or asked with
    ``DCSMS_CPU_LATENCY_US=0``); the kernel's value comes back when it exits, also when it is
    killed (the kernel withdraws a dead process's request). With ``off`` it asks for
    nothing."""
    before = read_latency_us()
    assert before is not None and before > 0, "another process holds 0 us: cannot tell"
    env = {**os.environ, RT_PRIORITY_ENV: "7"}
    env.pop(CPU_LATENCY_ENV, None)
    if value is not None:
        env[CPU_LATENCY_ENV] = value
    proc = subprocess.Popen([sys.executable, "-m", "dcsms_ros.nodes.sensor_decoupling",
                             "--ros-args", "-r", "__ns:=/qos_probe"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        fifo = False
        seen = set()
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.2)
            seen.add(read_latency_us())
            fifo = fifo or _has_fifo_thread(proc.pid)
            if fifo and (value == "off" or 0 in seen):
                time.sleep(1.0)  # what it holds, it holds from its start on
                seen.add(read_latency_us())
                break
        assert fifo, "the hot thread never ran under SCHED_FIFO"
        if value == "off":
            assert seen == {before}, seen
        else:  # the kernel's value until the hot loop started, 0 from then on
            assert 0 in seen and seen <= {0, before}, seen
    finally:
        if proc.poll() is None:
            proc.send_signal(how)
        out = proc.communicate(timeout=30)[0]
    assert read_latency_us() == before, out
