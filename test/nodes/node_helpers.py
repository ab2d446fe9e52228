"""Helpers of the node tests (imported by the test modules; fixtures are in conftest.py)."""

from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosmsgs import stamp_ns
from sensor_msgs.msg import JointState

from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.nodes.plant_simulator import PlantSimulatorNode
from dcsms_ros.ros import qos


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


def realtime_plant(c: Context, cfg: SystemConfig, probe_name: str, handshake_timeout_s: float,
                   deep: bool = False) -> tuple[PlantSimulatorNode, Node, list[int]]:
    """A real-time plant of fb_stage1 alone that runs until stopped, a probe node and the raw
    samples' stamps (ns) the probe receives (``deep``: a reader that keeps the first one)."""
    plant = PlantSimulatorNode(context=c, parameter_overrides=overrides(
        cfg, schedule="realtime", controllers=["fb_stage1"],
        handshake_timeout_s=handshake_timeout_s, duration_s=0.0))
    probe = rclpy.create_node(probe_name, context=c)
    raw: list[int] = []
    probe.create_subscription(JointState, topics.SENSORS_RAW,
                              lambda m: raw.append(stamp_ns(m.header.stamp)),
                              qos.stream_pub(False) if deep else qos.stream_sub(False))
    return plant, probe, raw
