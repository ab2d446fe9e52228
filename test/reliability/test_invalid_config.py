"""Invalid parameters, YAML files, mode names: rejected with a reason, the graph unchanged."""

from __future__ import annotations

import math

from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter
from rel_harness import Graph, Probe, assert_clean, call, report
from test_trip import _call

from dcsms_ros.core.modes import Mode

GAIN = "feedback.stage1.gain"
# (parameter, bad value, what makes it bad)
BAD_PARAMS = [
    (GAIN, [0.0, 0.0, -1.5e4, 0.0, 0.0, 0.0], "negative"),
    (GAIN, [0.0, 0.0, math.nan, 0.0, 0.0, 0.0], "NaN"),
    (GAIN, [0.0, 0.0, 1.5e4], "3 values for 6"),
    ("control.input_timeout_s", -0.01, "negative"),
    ("control.input_timeout_s", math.nan, "NaN"),
    ("control.fade_time_s", 1e6, "out of range"),
    ("feedback.stage1.highpass_hz", 1e9, "above Nyquist"),
    ("plant.rate_hz", 1000.0, "read-only"),
]
BAD_YAML = {
    "syntax": "/**:\n  ros__parameters:\n    plant.mass: [1, 2\n",
    "negative mass": "/**:\n  ros__parameters:\n    m1: -5.0\n",
    "unknown name": "/**:\n  ros__parameters:\n    plant.no_such_thing: 1.0\n",
    "NaN gain": "/**:\n  ros__parameters:\n    feedback.stage1.gain: [0, 0, .nan, 0, 0, 0]\n",
}


def test_invalid_values_files_and_modes_are_rejected(ctx, cfg, tmp_path):
    """Bad set_parameters, YAML and mode names: refused with a reason, exit 2, graph unchanged."""
    probe = Probe(ctx)
    (tmp_path / "graph").mkdir()
    # the CLI calls below load this 2-core box; a load-induced trip is test_trip's business
    graph = Graph(cfg, tmp_path / "graph", mode=Mode.DFBC,
                  extra={"mode_switch": {"trip_enabled": False}})
    node = "/dcsms/fb_stage1"
    reasons: dict[str, str] = {}
    cli: dict[str, tuple[int, str]] = {}
    try:
        probe.wait(lambda: float(probe.value("plant_simulator", "sim_time_s", "0")) > 1.0,
                   90.0, "plant running")
        for name, value, why in BAD_PARAMS:
            req = SetParameters.Request(parameters=[Parameter(name, value=value)
                                                    .to_parameter_msg()])
            res = _call(probe, SetParameters, f"{node}/set_parameters", req).results[0]
            reasons[f"{name} {why}"] = "accepted!" if res.successful else res.reason
        got = _call(probe, GetParameters, f"{node}/get_parameters",
                    GetParameters.Request(names=[GAIN, "control.input_timeout_s"])).values
        for label, text in BAD_YAML.items():
            path = tmp_path / f"{label.replace(' ', '_')}.yaml"
            path.write_text(text)
            r = call(["up", "--config", str(path), "--duration", "1"])
            cli[f"up --config ({label})"] = (r.returncode, r.stderr)
        for args in (["mode", "SKYHOOK"], ["up", "--mode", "turbo"],
                     ["up", "--set", "control.input_timeout_s=-1"],
                     ["up", "--set", f"{GAIN}=[0,0,nan,0,0,0]"]):
            r = call(args)
            cli[" ".join(args)] = (r.returncode, r.stderr)
        samples = int(probe.value("plant_simulator", "sample"))
        probe.wait(lambda: int(probe.value("plant_simulator", "sample")) > samples, 10.0,
                   "the plant still steps")
        still = (probe.modes[-1][1], probe.value("fb_stage1", "gain"))
        timeouts = probe.value("plant_simulator", "stale_events")
    finally:
        codes = graph.stop()
        probe.close()
    accepted = [k for k, v in reasons.items() if v == "accepted!"]
    report("7", f"{len(BAD_PARAMS)} invalid set_parameters, {len(BAD_YAML)} bad YAML files, "
           "unknown modes, bad --set", "all rejected with a reason; running graph unchanged",
           f"{len(reasons) - len(accepted)}/{len(reasons)} parameters and "
           f"{sum(c == 2 for c, _ in cli.values())}/{len(cli)} CLI calls (exit 2) rejected",
           reasons=reasons, cli={k: v[0] for k, v in cli.items()}, stale_events=timeouts)
    assert not accepted, accepted
    assert all(len(r) > 10 for r in reasons.values()), reasons
    assert list(got[0].double_array_value) == cfg.params[GAIN], "gain changed"
    assert got[1].double_value == cfg.control.input_timeout_s, "timeout changed"
    for label, (code, err) in cli.items():
        assert code == 2, f"{label}: exit {code}: {err}"
        assert "Traceback" not in err and err.startswith("dcsms: error:"), f"{label}: {err}"
        assert len(err.strip().splitlines()) == 1, f"{label}: not one line: {err}"
    assert still == ("DFBC", "1.000"), still
    assert all(c == 0 for c in codes.values()), codes
    assert_clean(graph.logs())
