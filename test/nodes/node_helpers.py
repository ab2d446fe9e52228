"""Helpers of the node tests (imported by the test modules; fixtures are in conftest.py)."""

from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.parameter import Parameter

from dcsms_ros.core.config import SystemConfig


def overrides(cfg: SystemConfig, **extra: object) -> list[Parameter]:
    """Parameter overrides that give a node ``cfg`` (as ``--params-file`` would) plus ``extra``."""
    flat = {k: v for k, v in (cfg.params or {}).items() if not (isinstance(v, list) and not v)}
    flat.update(extra)
    return [Parameter(k, value=v) for k, v in flat.items()]


def spin_until(executor: Executor, cond: Callable[[], bool], timeout: float) -> bool:
    """Spin until ``cond()`` or ``timeout`` seconds; returns ``cond()``."""
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return cond()


def executor_for(c: Context, *nodes: object) -> SingleThreadedExecutor:
    """A single-threaded executor in context ``c`` with ``nodes`` added."""
    ex = SingleThreadedExecutor(context=c)
    for n in nodes:
        ex.add_node(n)
    return ex
