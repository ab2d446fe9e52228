"""In-process lockstep graph: a silent controller is a counted fault, never a hang."""

from __future__ import annotations

import time

import numpy as np
import rclpy
from node_helpers import executor_for, overrides, spin_until
from rosgraph_msgs.msg import Clock
from rosmsgs import stamp_ns
from sensor_msgs.msg import JointState

from dcsms_ros.core import topics
from dcsms_ros.core.engine import simulate
from dcsms_ros.core.modes import Mode
from dcsms_ros.nodes.feedback_controller import FeedbackControllerNode
from dcsms_ros.nodes.plant_simulator import PlantSimulatorNode
from dcsms_ros.nodes.sensor_decoupling import SensorDecouplingNode
from dcsms_ros.ros import qos


def test_absent_controller_times_out_and_equals_batch_without_it(ctx, cfg):
    """Without ff_stage1 the plant times out twice, marks it absent and equals batch DFBC."""
    duration = 0.1
    common = {"schedule": "lockstep", "control.lockstep_timeout_s": 0.05}
    plant = PlantSimulatorNode(context=ctx, parameter_overrides=overrides(
        cfg, duration_s=duration, absent_after=2, lockstep_retry_s=0.02, handshake_timeout_s=1.0,
        **common))
    dec = SensorDecouplingNode(context=ctx, parameter_overrides=overrides(cfg, **common))
    fbs = [FeedbackControllerNode(f"fb_stage{i}", context=ctx, parameter_overrides=overrides(
        cfg, stage=i, enabled=True, **common)) for i in (1, 2)]
    probe = rclpy.create_node("probe", context=ctx)
    applied: dict[int, np.ndarray] = {}
    probe.create_subscription(JointState, topics.ACTUATORS_APPLIED, lambda m: applied.__setitem__(
        stamp_ns(m.header.stamp), np.array(m.effort)), qos.stream_pub(True))
    clock: list[int] = []
    probe.create_subscription(Clock, topics.CLOCK, lambda m: clock.append(stamp_ns(m.clock)),
                              qos.clock())
    ex = executor_for(ctx, plant, dec, *fbs, probe)
    t0 = time.monotonic()
    assert spin_until(ex, lambda: plant.finished, 60.0), "the plant hung"
    wall = time.monotonic() - t0
    steps = int(round(duration * cfg.plant.rate_hz))
    spin_until(ex, lambda: len(applied) >= steps, 5.0)
    assert plant.sim.k == steps
    assert plant.faults == {"fb_stage1": 0, "fb_stage2": 0, "ff_stage1": 2}
    assert plant.controller_state("ff_stage1") == "absent"
    # a missing controller contributes zero force: the same as its disabled (DFBC) batch run
    ref = simulate(cfg, Mode.DFBC, duration)
    got = np.array([applied[k] for k in sorted(applied)])
    np.testing.assert_array_equal(got, ref.applied)
    # /clock (serialized by the plant, cdr.clock_bytes): the sample times every 1/100 s
    assert clock, "no /clock"
    every = int(round(cfg.plant.rate_hz / 100.0))  # clock_rate_hz's default
    assert clock == sorted(set(clock))
    period_ns = round(every * 1e9 / cfg.plant.rate_hz)
    assert all(c % period_ns == 0 and 0 <= c < duration * 1e9 for c in clock), clock
    print(f"in-process lockstep with one absent controller: {steps} samples in {wall:.2f} s, "
          f"{len(clock)} /clock")
    ex.shutdown()
