"""Fixtures of the node tests: a private ROS domain per test and private rclpy contexts."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context

from dcsms_ros.core.config import SystemConfig, load_config

REPO = Path(__file__).resolve().parents[2]
TABLE1 = REPO / "config" / "table1.yaml"
_counter = itertools.count()


def unique_domain() -> int:
    """A ROS domain id in 1..101 derived from a counter and the pid (parallel runs differ)."""
    return 1 + (os.getpid() * 7 + next(_counter) * 13) % 101


@pytest.fixture
def domain(monkeypatch: pytest.MonkeyPatch) -> int:
    """This test's own ROS_DOMAIN_ID (also exported to child processes), localhost only."""
    d = unique_domain()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(d))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    return d


@pytest.fixture
def ctx(domain: int) -> Iterator[Context]:
    """An initialised private rclpy context in this test's domain."""
    c = Context()
    rclpy.init(args=[], context=c, domain_id=domain)
    yield c
    rclpy.try_shutdown(context=c)


@pytest.fixture
def cfg() -> SystemConfig:
    """The paper's Table 1 preset."""
    return load_config(TABLE1)
