"""Fixtures shared by the ROS tests: a private ROS domain per test, private rclpy contexts and
the Table 1 preset."""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context

from dcsms_ros.core.config import SystemConfig, load_config

TABLE1 = Path(__file__).resolve().parents[1] / "config" / "table1.yaml"
# Every test of one run gets a different domain (Fast DDS allows 0..232 with default ports);
# the pid seeds the order so two runs side by side rarely pick the same ids at the same time.
_DOMAINS = iter(random.Random(os.getpid()).sample(range(1, 230), 229))


def pytest_addoption(parser: pytest.Parser) -> None:
    """``--soak``: run the reliability soak for its full duration (10 minutes)."""
    parser.addoption("--soak", action="store_true", default=False,
                     help="run test/reliability/test_soak.py for 10 minutes (default: 25 s)")


def unique_domain() -> int:
    """The next unused ROS domain id of this test run."""
    return next(_DOMAINS)


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
