"""The plant simulator node's own parameters (outside the system schema), read once at start."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rclpy.node import Node

from dcsms_ros.analysis.replay import load_ground, parse_ground_spec
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import controller_ids
from dcsms_ros.errors import ConfigError
from dcsms_ros.ros.params import declare_local


@dataclass(frozen=True)
class PlantOptions:
    """Node-local settings of ``plant_simulator``; see :func:`declare_plant_options`."""

    duration_s: float
    controllers: tuple[str, ...]
    retry_s: float
    absent_after: int
    handshake_timeout_s: float
    publish_truth: bool
    clock_rate_hz: float
    timing_file: str
    status_period_s: float
    ground_from: str
    trip_gate: bool
    hold_at_s: float
    excitation: bool


def declare_plant_options(node: Node, num_stages: int) -> PlantOptions:
    """Declare the node's own parameters (descriptors, units, ranges) and return their values.

    Raises
    ------
    ConfigError
        ``controllers`` names an id that an ``num_stages``-stage graph does not have.
    """
    ids = controller_ids(num_stages)
    wanted = declare_local(node, "controllers", list(ids), "Controller ids whose force topics "
                           "are summed (and, in lockstep, waited for)")
    unknown = sorted(set(wanted) - set(ids))
    if unknown:
        raise ConfigError(f"node plant_simulator: unknown controllers {unknown}; expected "
                          f"some of {list(ids)}")
    return PlantOptions(
        duration_s=declare_local(node, "duration_s", 0.0, "Simulated time after which the node "
                                 "exits; 0 runs until stopped [s]", lo=0.0, hi=1e9),
        # the batch engine sums in controller_ids order; so must the plant, bit for bit
        controllers=tuple(c for c in ids if c in wanted),
        retry_s=declare_local(node, "lockstep_retry_s", 0.2, "Lockstep: republish a sample "
                              "when a reply is missing after this wall time [s]", lo=0.001,
                              hi=60.0),
        absent_after=declare_local(node, "absent_after", 3, "Lockstep: consecutive timeouts "
                                   "after which a controller is absent", lo=1, hi=1000000),
        handshake_timeout_s=declare_local(node, "handshake_timeout_s", 10.0, "Longest wait for "
                                          "the graph before sample 0 [s]", lo=0.0, hi=600.0),
        publish_truth=declare_local(node, "publish_truth", True, "Publish the true velocities "
                                    "on <namespace>/truth/<body>"),
        clock_rate_hz=declare_local(node, "clock_rate_hz", 100.0, "Rate of /clock (every "
                                    "node's sim time, used only by timers, logs and the "
                                    "real-time watchdog; stamps carry the sample time): each "
                                    "/clock message costs a callback in every node [Hz]",
                                    lo=1.0, hi=1e5),
        timing_file=declare_local(node, "timing_file", "", "Benchmarks: write the wall time of "
                                  "every sample and the force latencies to this .npz at exit; "
                                  "empty: off"),
        status_period_s=declare_local(node, "status_period_s", 1.0, "Diagnostics period [s]",
                                      lo=0.05, hi=60.0),
        ground_from=declare_local(node, "ground_from", "", "Replay the ground velocity of this "
                                  "bag (BAG or BAG:TOPIC, resampled to plant.rate_hz) instead of "
                                  "white noise; empty: white noise"),
        trip_gate=declare_local(node, "trip_gate", False, "Lockstep: at every trip checkpoint "
                                "ask mode_switch (trip/check) and wait for its verdict "
                                "(trip/checked), so the trip lands on the batch engine's "
                                "sample; false: no wait"),
        hold_at_s=declare_local(node, "hold_at_s", 0.0, "Lockstep: stop before the sample at "
                                "this simulated time until the value changes (a scheduled mode "
                                "switch happens meanwhile); 0: no hold [s]", read_only=False,
                                lo=0.0, hi=1e9),
        excitation=declare_local(node, "excitation", False, "Sum the excitation wrench of "
                                 "force/excitation (frame_id: the stage) with the controllers' "
                                 "before allocation; in lockstep wait for it like for a "
                                 "controller"),
    )


def replayed_ground(spec: str, cfg: SystemConfig) -> np.ndarray | None:
    """Ground velocity (K, dof) read from ``spec`` (``BAG[:TOPIC]``), or None for white noise."""
    if not spec:
        return None
    bag, topic = parse_ground_spec(spec)
    return load_ground(bag, topic, cfg.plant.rate_hz, cfg.plant.dof)
