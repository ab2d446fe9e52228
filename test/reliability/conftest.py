"""Fixtures of the reliability tests: a private ROS domain per test, a probe context, config."""

from __future__ import annotations

import os
import random
from collections.abc import Iterator

import pytest
import rclpy
from rclpy.context import Context

from dcsms_ros.core.config import SystemConfig, load_config

TABLE1 = os.path.join(os.path.dirname(__file__), "..", "..", "config", "table1.yaml")
# 150..229: apart from test/nodes (1..101) and test_recorder (100..229 random, rarely clashes)
_DOMAINS = iter(random.Random(os.getpid() + 6).sample(range(150, 230), 80))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--soak", action="store_true",
                     help="run the reliability soak for 10 minutes (or DCSMS_SOAK_S seconds)")


@pytest.fixture
def domain(monkeypatch: pytest.MonkeyPatch) -> int:
    """This test's own ROS_DOMAIN_ID (also for child processes), localhost discovery."""
    d = next(_DOMAINS)
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
