"""An unstable gain set through set_parameters: the trip latches Passive within 1 s, until reset."""

from __future__ import annotations

import time

import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rel_harness import Graph, Probe, assert_clean, mono_ns, report
from std_srvs.srv import Trigger

from dcsms_ros.core import topics
from dcsms_ros.core.modes import Mode

TRIP_WITHIN_S = 1.0
#: Wall-clock bound: 1 s plus what a loaded 2-core box adds (plant slower than real time).
WALL_BOUND_S = 3.0
FACTOR = 50.0


def _call(probe: Probe, srv_type, name: str, request, timeout: float = 20.0):
    client = probe.node.create_client(srv_type, name)
    assert client.wait_for_service(timeout_sec=timeout), f"{name} not available"
    fut = client.call_async(request)
    end = time.monotonic() + timeout
    while not fut.done():
        assert time.monotonic() < end, f"{name}: no answer"
        time.sleep(0.01)
    return fut.result()


# Multi-process timing on a shared 2-core machine: a scheduling hiccup can miss a bound
# once; two reruns keep CI meaningful (every attempt must fail for a red run).
@pytest.mark.flaky(reruns=2, reruns_delay=2)
def test_unstable_gain_trips_to_passive_and_latches(ctx, cfg, tmp_path):
    """fb_stage2 gain x50 via set_parameters: Passive within 1 s, reason given, latched
    (without the supervisor, ``supervisor.enabled`` false: the supervisor would re-engage
    after its hold; test/nodes/test_supervisor_graph.py covers it)."""
    probe = Probe(ctx)
    # the stability guard would refuse the gain; the trip is the last line of defence
    graph = Graph(cfg, tmp_path, mode=Mode.DFBC, allow_unstable=True,
                  extra={"mode_switch": {"supervisor.enabled": False}})
    name = "feedback.stage2.gain"
    gain = [FACTOR * g for g in cfg.params[name]]
    try:
        probe.wait(lambda: float(probe.value("plant_simulator", "sim_time_s", "0")) > 2.0,
                   90.0, "plant running")
        probe.wait(lambda: probe.value("fb_stage2", "gain") == "1.000", 10.0, "DFBC faded in")
        req = SetParameters.Request(parameters=[Parameter(name, value=gain).to_parameter_msg()])
        res = _call(probe, SetParameters, f"{topics.NAMESPACE}/fb_stage2/set_parameters", req)
        t_set = mono_ns()
        assert res.results[0].successful, res.results[0].reason
        probe.wait(lambda: bool(probe.modes) and probe.modes[-1][1] == "Passive", 10.0,
                   "mode Passive after the unstable gain")
        t_mode = probe.modes[-1][0]
        probe.wait(lambda: probe.value("mode_switch", "tripped") == "True", 5.0, "trip reported")
        probe.wait(lambda: int(probe.value("fb_stage2", "params_changed_at_ns")) > 0, 5.0,
                   "fb_stage2 reports its change")
        ms = probe.diag["mode_switch"]
        # plant time from the first sample with the new gain to the sample that tripped
        sim_s = (int(ms["trip_sample_ns"]) - int(probe.value("fb_stage2",
                                                             "params_changed_at_ns"))) / 1e9
        wall_s = (int(ms["trip_mono_ns"]) - t_set) / 1e9
        latency = (t_mode - t_set) / 1e9
        reason = probe.diag_msgs["mode_switch"]
        time.sleep(2.0)  # latched: nothing switches back by itself
        modes_after = [m for t, m in probe.modes if t > t_set]
        still = probe.value("mode_switch", "tripped")
        # faded out (control.fade_time_s of plant time; a starved controller may take longer)
        probe.wait(lambda: all(probe.value(c, "gain") == "0.000"
                               for c in ("fb_stage1", "fb_stage2")), 15.0, "loops faded out")
        gains = {c: probe.value(c, "gain") for c in ("fb_stage1", "fb_stage2")}
        refused = _call(probe, Trigger, topics.set_mode_service("dfbc"), Trigger.Request())
        # a reset while the table still rings (Passive decays slowly) would trip again at once
        limit = cfg.control.trip_rms_mps
        probe.wait(lambda: all(float(x) < 0.5 * limit for k, v in probe.diag.get(
            "mode_switch", {}).items() if k.startswith("rms_") for x in v.split()), 60.0,
            "the table settles in Passive")
        reset = _call(probe, Trigger, topics.RESET_TRIP, Trigger.Request())
        probe.wait(lambda: probe.value("mode_switch", "tripped") == "False", 5.0,
                   "trip cleared by reset")
        mode_after_reset = probe.modes[-1][1]
    finally:
        codes = graph.stop()
        probe.close()
    log = (tmp_path / "mode_switch.log").read_text()
    report("6", f"fb_stage2 gain x{FACTOR:g} via set_parameters (real time, DFBC)",
           f"latched Passive: '{reason}'; held until /dcsms/reset_trip",
           f"{sim_s * 1e3:.0f} ms plant time to trip; {latency * 1e3:.0f} ms wall to Passive on "
           f"/dcsms/mode (trip decided {wall_s * 1e3:.0f} ms wall after the change)",
           latency_s=latency, sim_s=sim_s, wall_trip_s=wall_s)
    assert sim_s <= TRIP_WITHIN_S, f"tripped {sim_s:.2f} s of plant time after the change"
    # wall clock: the plant itself may run slower than real time on a loaded box
    assert latency <= WALL_BOUND_S, f"Passive only after {latency:.2f} s wall"
    assert reason.startswith("TRIPPED: stage") and "RMS" in reason, reason
    assert "instability trip" in log
    assert modes_after == ["Passive"], modes_after
    assert still == "True" and all(g == "0.000" for g in gains.values()), (still, gains)
    assert not refused.success and "trip" in refused.message.lower(), refused.message
    assert reset.success and mode_after_reset == "Passive", (reset.message, mode_after_reset)
    assert all(c == 0 for c in codes.values()), codes
    assert_clean(graph.logs())
