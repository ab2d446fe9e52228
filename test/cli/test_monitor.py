"""`dcsms up`'s status line from the plant's reports on /diagnostics (a real publisher, DDS)."""

from __future__ import annotations

import time

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from dcsms_ros.cli.monitor import GraphMonitor
from dcsms_ros.core import topics
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.graph import define_graph
from dcsms_ros.ros import qos

pytestmark = pytest.mark.ros


def _report(n: int, sample: int, rate_hz: float, finished: bool) -> DiagnosticArray:
    """The plant's report number ``n`` (the key ``n`` tells the test it arrived)."""
    arr = DiagnosticArray()
    arr.status = [DiagnosticStatus(name="dcsms/plant_simulator", message="running", values=[
        KeyValue(key="n", value=str(n)),
        KeyValue(key="sample", value=str(sample)),
        KeyValue(key="sim_time_s", value=f"{sample / 2000.0:.6f}"),
        KeyValue(key="achieved_rate_hz", value=f"{rate_hz:.1f}"),
        KeyValue(key="finished", value=str(finished))])]
    return arr


@pytest.mark.parametrize("reports, shown", [
    # the plant's report at its last sample, then its closing one at once (no sample between)
    (((40000, 1999.0, True), (40000, 0.0, True)), "rate= 1999.0 Hz"),
    # a stall: no sample in the window of a running plant
    (((38000, 1999.0, False), (38000, 0.0, False)), "rate=    0.0 Hz"),
    # samples in the final window: its own rate
    (((38000, 1999.0, False), (38010, 5.0, True)), "rate=    5.0 Hz"),
], ids=["final", "stall", "final-with-samples"])
def test_status_rate_ignores_an_empty_final_window(ctx, cfg: SystemConfig, reports: tuple,
                                                   shown: str) -> None:
    """The final status line shows the last measured rate, not the 0 Hz of the plant's
    closing report (sent at once after its previous one, no sample between); a plant that
    stopped stepping before finishing still shows 0 Hz."""
    mon = GraphMonitor(define_graph(cfg), ctx)
    node = rclpy.create_node("plant_reports", context=ctx)
    try:
        pub = node.create_publisher(DiagnosticArray, topics.DIAGNOSTICS, qos.status())
        end = time.monotonic() + 10.0
        while pub.get_subscription_count() == 0 and time.monotonic() < end:
            mon.executor.spin_once(timeout_sec=0.02)
        for n, (sample, rate, done) in enumerate(reports):
            pub.publish(_report(n, sample, rate, done))
            end = time.monotonic() + 10.0
            while mon.diag.get("plant_simulator", {}).get("n") != str(n) and \
                    time.monotonic() < end:
                mon.executor.spin_once(timeout_sec=0.02)
        assert mon.diag["plant_simulator"]["sample"] == str(reports[-1][0])
        assert shown in mon.status_line(), mon.status_line()
    finally:
        mon.close()
        node.destroy_node()
