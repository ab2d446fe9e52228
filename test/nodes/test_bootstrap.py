"""The rclpy bootstrap: one context per block, stop signals as a flag, guaranteed shutdown."""

from __future__ import annotations

import os
import signal
import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from dcsms_ros.ros.context import ros_context, spin_until
from dcsms_ros.rosenv import DEFAULT_RANGE, DISCOVERY_RANGE_VAR


def test_signals_set_the_flag_and_end_the_spin(domain: int) -> None:
    """With signals=True, SIGTERM (and SIGINT) only set the flag: the spin loop returns, no
    exception; the first signal and its time are kept; the old handlers come back after."""
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with ros_context([], signals=True) as ros:
        assert ros.context.ok() and not ros.stop
        node = Node("bootstrap_probe", context=ros.context)
        executor = SingleThreadedExecutor(context=ros.context)
        executor.add_node(node)
        node.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGTERM))
        t0 = time.time_ns()
        assert spin_until(executor, lambda: bool(ros.stop), timeout_s=10.0)
        os.kill(os.getpid(), signal.SIGINT)  # a second signal does not overwrite the first
        assert ros.stop.signum == signal.SIGTERM and ros.stop.at_ns >= t0
        executor.shutdown()
        node.destroy_node()
    assert not ros.context.ok()
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_context_is_shut_down_when_the_block_raises(domain: int) -> None:
    """An exception passes through unchanged, and the context is shut down all the same; the
    process's own handlers are untouched without signals=True."""
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(RuntimeError, match="boom"), ros_context([]) as ros:
        assert signal.getsignal(signal.SIGINT) is before
        raise RuntimeError("boom")
    assert not ros.context.ok()


def test_spin_until_gives_up_after_its_timeout(domain: int) -> None:
    with ros_context([]) as ros:
        executor = SingleThreadedExecutor(context=ros.context)
        t0 = time.monotonic()
        assert not spin_until(executor, lambda: False, timeout_s=0.3)
        assert 0.25 <= time.monotonic() - t0 < 2.0
        executor.shutdown()


def test_discovery_stays_local_unless_chosen(domain: int, monkeypatch) -> None:
    """No range set: the bootstrap sets localhost before the first participant; a range the
    user chose is kept."""
    monkeypatch.delenv(DISCOVERY_RANGE_VAR)
    with ros_context([]):
        assert os.environ[DISCOVERY_RANGE_VAR] == DEFAULT_RANGE
    monkeypatch.setenv(DISCOVERY_RANGE_VAR, "OFF")  # no discovery at all: safe in a test
    with ros_context([]):
        assert os.environ[DISCOVERY_RANGE_VAR] == "OFF"
