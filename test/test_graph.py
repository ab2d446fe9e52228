"""One graph definition: N stages, namespace, parameters, extension by one node."""

from __future__ import annotations

from pathlib import Path

import pytest

from dcsms_ros.core import topics
from dcsms_ros.core.config import load_config, with_overrides
from dcsms_ros.core.modes import Mode
from dcsms_ros.errors import ConfigError
from dcsms_ros.graph import NodeSpec, define_graph, format_cpus, parse_cpus, spec_from_dict

TABLE1 = Path(__file__).resolve().parents[1] / "config" / "table1.yaml"


def test_nodes_parameters_and_params_file() -> None:
    cfg = load_config(TABLE1)
    spec = define_graph(cfg, schedule="lockstep", mode=Mode.FBC, namespace="lab/t2",
                        duration_s=3.0, hold_at_s=1.5)
    assert spec.namespace == "/lab/t2"
    assert [n.name for n in spec.nodes] == ["mode_switch", "fb_stage1", "fb_stage2",
                                           "ff_stage1", "sensor_decoupling", "plant_simulator"]
    assert [n.control_path for n in spec.nodes] == [False, True, True, True, True, True]
    doc = spec.params_document()
    assert doc["/**"]["ros__parameters"]["schedule"] == "lockstep"
    assert doc["/**"]["ros__parameters"]["plant.num_stages"] == 2
    assert doc["/lab/t2/fb_stage1"]["ros__parameters"]["enabled"] is True
    assert doc["/lab/t2/fb_stage2"]["ros__parameters"] == {"enabled": False,
                                                           "allow_unstable": False, "stage": 2}
    plant = doc["/lab/t2/plant_simulator"]["ros__parameters"]
    assert plant["trip_gate"] is True and plant["hold_at_s"] == 1.5 and plant["duration_s"] == 3
    assert spec_from_dict(spec.to_dict()) == spec
    nm = spec.names
    assert nm.velocity("stage1") == "/lab/t2/velocity/stage1"
    assert nm.local_status("lab/t2/plant_simulator/fb_stage1") == "plant_simulator/fb_stage1"
    assert nm.local_status("dcsms/plant_simulator") is None
    assert "/lab/t2/truth/ground" in spec.stream_topics()
    waits = spec.recorded_observed()
    assert {*spec.stream_topics(), "/lab/t2/mode", "/lab/t2/config"} == set(waits)
    assert spec.recorded_observed(["/lab/t2/mode", "/lab/t2/sensors/raw", "/other"]) == [
        "/lab/t2/sensors/raw", "/lab/t2/mode"]


def test_three_stages_and_real_time_has_no_trip_gate() -> None:
    cfg = with_overrides(load_config(TABLE1), {"plant.num_stages": 3, "stage3.mass": 500.0})
    spec = define_graph(cfg, mode=Mode.DFBC)
    names = [n.name for n in spec.nodes]
    assert [n for n in names if n.startswith("fb_")] == ["fb_stage1", "fb_stage2", "fb_stage3"]
    assert all(spec.node(f"fb_stage{i}").params["enabled"] for i in (1, 2, 3))
    assert spec.node("plant_simulator").params["trip_gate"] is False
    assert spec.node("fb_stage3").params["stage"] == 3


def test_one_more_node_and_bad_namespace() -> None:
    spec = define_graph(load_config(TABLE1))
    more = spec.with_node(NodeSpec("excitation", "mode_switch", {"x": 1}))
    assert more.nodes[-1].name == "excitation" and len(more.nodes) == len(spec.nodes) + 1
    assert more.params_document()["/dcsms/excitation"] == {"ros__parameters": {"x": 1}}
    with pytest.raises(ConfigError, match="namespace"):
        define_graph(load_config(TABLE1), namespace="/bad-name")
    assert topics.check_namespace("/") == "/"


@pytest.mark.parametrize("text, cpus", [("", set()), ("1", {1}), ("0,2-3", {0, 2, 3}),
                                        (" 3 , 1 ", {1, 3}), ("2-2", {2})])
def test_cpu_lists_as_taskset_takes_them(text: str, cpus: set[int]) -> None:
    """``--rt-cpus``/``$DCSMS_RT_CPUS``: single CPUs and ranges, and back."""
    assert parse_cpus(text) == cpus
    assert parse_cpus(format_cpus(cpus)) == cpus


@pytest.mark.parametrize("text", ["a", "1,", ",1", "1,,2", "3-1", "-1", "1-", "1.5"])
def test_malformed_cpu_lists_are_refused(text: str) -> None:
    """Anything else is a ValueError that names the list."""
    with pytest.raises(ValueError, match="not a CPU list"):
        parse_cpus(text)
